"""
The driver layer: the manager the node calls and the parts it builds, one job per module.

manager: the facade (one method per request, each answering a Result); roles: what the cycle
loop and the follower call on it (they never import it); servo: what is known of each servo (and
the small shared helpers); link: one-off transactions on one servo; setup: configuration, hold
and mode switch steps; adapter: the USB adapter's real latency timer; goals: the goal queue (and
the ends of a joint's range); loop: the one cycle loop (read, steps, write, publish, pacing; its
own thread or a timer), which the node and the bench drive; cycle: the read in flight, with
read_plan (what is read and how), samples (taking them) and goal_write (the goals in one write
per protocol); state_block: the packed state block and the goal slot; rates: the loop's rate
measures; recovery: restarts, reboots, rejoins and port loss; pairs: a joint on two servos;
port_watch: port loss and reconnection; transports: `port` by name; tasks: step-wise
activities; clock: dating samples; services: the requests of the node's services; follow: a
leader's joint_states copied each cycle; context: what the parts share.
"""
