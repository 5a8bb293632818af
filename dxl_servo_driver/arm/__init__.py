"""
The arm's logic, with no bus and no ROS: what the node's arm requests mean.

trajectory: a FollowJointTrajectory goal checked and sampled; commands: a JointState command
split by each joint's mode; gripper: a gripper's travel, goals and grasp detection. Only ros/
uses them.
"""
