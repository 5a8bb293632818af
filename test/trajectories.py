"""Trajectories as a client sends them: a topic message, or a FollowJointTrajectory goal."""

from typing import Any, Sequence, Tuple

from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

# Each point: its time from the start (s), its positions, its velocities.
Plan = Sequence[Tuple[float, Sequence[float], Sequence[float]]]


def trajectory(joints: Sequence[str], points: Plan) -> JointTrajectory:
    """Return the plan as a JointTrajectory message (no stamp: start at once)."""
    msg = JointTrajectory()
    msg.joint_names = list(joints)
    for t, positions, velocities in points:
        point = JointTrajectoryPoint()
        point.positions = [float(p) for p in positions]
        point.velocities = [float(v) for v in velocities]
        point.time_from_start = Duration(sec=int(t), nanosec=int(round((t % 1) * 1e9)))
        msg.points.append(point)
    return msg


def goal_of(joints: Sequence[str], plan: Plan, **fields: Any) -> Any:
    """Return the plan as a FollowJointTrajectory goal, with other goal fields set by name."""
    goal = FollowJointTrajectory.Goal()
    goal.trajectory = trajectory(joints, plan)
    for name, value in fields.items():
        setattr(goal, name, value)
    return goal
