"""
The driver layer behind manager.Manager, one job per module.

servo: what is known of each servo (and the small shared helpers); link: one-off
transactions on one servo; setup: configuration, hold and mode switch steps; goals: the goal
queue; cycle: the cycle's state read and goal write; recovery: restarts, reboots, rejoins and
port loss; services: the requests of the node's services.
"""
