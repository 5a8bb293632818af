"""
The driver layer behind manager.Manager, one job per module.

servo: what is known of each servo (and the small shared helpers); link: one-off
transactions on one servo; setup: configuration, hold and mode switch steps; adapter: the USB
adapter's real latency timer; goals: the goal queue (and the ends of a joint's range); loop:
the one cycle loop (read, steps, write, publish, pacing; its own thread or a timer), which the
node and the bench drive; cycle: the read in flight, with read_plan (what is read and how),
samples (taking them) and goal_write (the goals in one write per protocol); rates: the loop's
rate measures; recovery: restarts, reboots, rejoins and port loss; pairs: a joint on two
servos; port_watch: port loss and reconnection; clock: dating samples; services: the requests
of the node's services.
"""
