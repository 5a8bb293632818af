"""
MoveIt's actions: control_msgs' FollowJointTrajectory, GripperCommand, ParallelGripperCommand.

ros2_controllers' joint_trajectory_controller is what MoveIt usually talks to for an arm: the
same codes and the same tolerances here mean MoveIt sees the same results. GripperCommand drives
a `gripper: true` joint with an effort limit and ends when it reached its goal, stalled on an
object (succeeded, stalled), stopped short, or was preempted, canceled or aborted.
ParallelGripperCommand (what MoveIt on Jazzy sends a parallel gripper) is the same goal given
as a sensor_msgs/JointState (the joint's name, position, and optionally the most velocity and
effort), its feedback and result the joint's state as a JointState.

A goal is read whole before anything moves; a refused one ends at once with its error_code and
an error_string naming the cause (accepted, then aborted: a rejected goal carries no result, and
MoveIt would only say "rejected"). An accepted goal becomes a trajectory of the arm's executor,
sampled by the bus cycle like a ~/joint_trajectory message; the cycle hands its feedback and
its end to the goal through a _Channel, and the goal's coroutine turns them into ROS messages
here, off the cycle thread.

Why a node and an executor of their own: rclpy's EventsExecutor (the node's default executor,
for its command latency) never delivers an action goal (rclpy 7.1: the goal request times
out). So the action servers live on `<node>_actions`, spun by a
SingleThreadedExecutor in the thread `dxl_actions`, under the driver node's own names
(`<node>/follow_joint_trajectory`): whatever the node's executor, MoveIt finds them where it
looks.
"""

from collections import deque
import math
import threading
import time
from typing import Any, Deque, Dict, List, Optional, Protocol, Sequence, Tuple

from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory, GripperCommand, ParallelGripperCommand
from dxl_servo_driver import config as cfg
from dxl_servo_driver.arm import gripper
from dxl_servo_driver.arm import trajectory as traj
from dxl_servo_driver.errors import BadRequest
from dxl_servo_driver.ros.arm import Arm
import rclpy
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import qos_profile_services_default, QoSProfile
from rclpy.task import Future
from trajectory_msgs.msg import JointTrajectoryPoint

__all__ = ['Actions']

Result = FollowJointTrajectory.Result

# The requests an action server's goal, cancel and result services hold before they are taken.
# The middleware's default (10, which joint_trajectory_controller shares) dropped all but ~15 of
# 50 goals sent at once, and their clients waited forever; a deeper queue costs only the
# requests that are really waiting. What a client can rely on: this many requests of each kind,
# from all its clients together, sent at once, are all answered.
ACTION_QUEUE_DEPTH = 1000
_REQUEST_QOS = QoSProfile(depth=ACTION_QUEUE_DEPTH, history=qos_profile_services_default.history,
                          reliability=qos_profile_services_default.reliability,
                          durability=qos_profile_services_default.durability)
_QUEUES = {'goal_service_qos_profile': _REQUEST_QOS, 'result_service_qos_profile': _REQUEST_QOS,
           'cancel_service_qos_profile': _REQUEST_QOS}


class GoalRefused(BadRequest):
    """A goal refused before anything moved: its error_code and why."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


class Host(Protocol):
    """What the actions need of the node."""

    arm: Arm
    config: cfg.DriverConfig
    context: Any

    @property
    def active(self) -> bool:
        """Return True while the node is in the active state: the cycle runs."""

    def get_name(self) -> str:
        """Return the node's name."""

    def get_namespace(self) -> str:
        """Return the node's namespace."""

    def get_fully_qualified_name(self) -> str:
        """Return the node's full name: the actions live under it."""

    def get_logger(self) -> Any:
        """Return the node's logger."""

    def get_clock(self) -> Any:
        """Return the node's clock (goal stamps are on it)."""


def _nothing(_: Any) -> None:
    """Wake the executor: a done callback makes it schedule, and so resume, what awaits."""


class _Channel:
    """From the cycle thread to one goal's coroutine: feedback samples, then its end."""

    def __init__(self, executor: Any) -> None:
        self._executor = executor
        self._lock = threading.Lock()
        self._events: Deque[Tuple[str, Any]] = deque()
        self._future: Optional[Future] = None

    def post(self, kind: str, payload: Any) -> None:
        """Hand over one event (any thread); a feedback not yet taken is replaced, not queued."""
        with self._lock:
            if kind == 'feedback' and self._events and self._events[-1][0] == 'feedback':
                self._events.pop()
            self._events.append((kind, payload))
            future, self._future = self._future, None
        if future is not None and not future.done():
            future.set_result(None)

    async def take(self) -> Tuple[str, Any]:
        """Return the next event, waiting for it without holding the executor."""
        while True:
            with self._lock:
                if self._events:
                    return self._events.popleft()
                future = Future(executor=self._executor)
                future.add_done_callback(_nothing)
                self._future = future
            await future


class _GoalListener:
    """A trajectory's (or gripper goal's) listener that forwards to a goal's channel."""

    def __init__(self, channel: _Channel, feedback_period_s: float) -> None:
        self._channel = channel
        self.feedback_period_s = feedback_period_s

    def feedback(self, sample: Any) -> None:
        self._channel.post('feedback', sample)

    def ended(self, outcome: Any) -> None:
        self._channel.post('ended', outcome)


def _duration_s(duration: Any) -> float:
    return duration.sec + duration.nanosec * 1e-9


def _duration(seconds: float) -> Duration:
    seconds = max(0.0, seconds)
    whole = int(seconds)
    return Duration(sec=whole, nanosec=min(999_999_999, int(round((seconds - whole) * 1e9))))


def _point(positions: Sequence[float], velocities: Sequence[float],
           since_start_s: float) -> JointTrajectoryPoint:
    point = JointTrajectoryPoint()
    point.positions = [float(value) for value in positions]
    point.velocities = [float(value) for value in velocities]
    point.time_from_start = _duration(since_start_s)
    return point


def _tolerance_value(where: str, field: str, value: float, default: float) -> float:
    """Return a JointTolerance field as used: 0 the default, -1 none (0 here), else itself."""
    if not math.isfinite(value) or (value < 0.0 and value != -1.0):
        raise GoalRefused(Result.INVALID_GOAL, f'{where}: {field} {value} is neither a '
                          'positive tolerance, 0 (the default) nor -1 (none)')
    if value == 0.0:
        return default
    return 0.0 if value == -1.0 else value


def goal_tolerances(goal: Any, joints: Tuple[str, ...], defaults: traj.Tolerances
                    ) -> traj.Tolerances:
    """Return the goal's tolerances over the defaults, or raise GoalRefused naming the fault."""
    index = {name: i for i, name in enumerate(joints)}
    tables: Dict[str, List[float]] = {
        'path_position': list(defaults.path_position),
        'path_velocity': list(defaults.path_velocity),
        'goal_position': list(defaults.goal_position),
        'goal_velocity': list(defaults.goal_velocity)}
    for kind, tolerances in (('path', goal.path_tolerance), ('goal', goal.goal_tolerance)):
        for tolerance in tolerances:
            where = f'{kind}_tolerance of {tolerance.name!r}'
            if tolerance.name not in index:
                raise GoalRefused(Result.INVALID_GOAL, f'{where}: no such joint in the '
                                  f'trajectory (its joints: {", ".join(joints)})')
            if tolerance.acceleration not in (0.0, -1.0):
                raise GoalRefused(Result.INVALID_GOAL, f'{where}: acceleration tolerances '
                                  'cannot be checked (a Dynamixel reports no acceleration); '
                                  'give 0 or -1')
            i = index[tolerance.name]
            for field in ('position', 'velocity'):
                table = tables[f'{kind}_{field}']
                table[i] = _tolerance_value(where, field, getattr(tolerance, field), table[i])
    if goal.component_path_tolerance or goal.component_goal_tolerance:
        raise GoalRefused(Result.INVALID_GOAL, 'component tolerances are for multi-DOF joints, '
                          'which this driver has none of')
    goal_time_s = _duration_s(goal.goal_time_tolerance)
    if goal_time_s < 0.0:
        raise GoalRefused(Result.INVALID_GOAL, f'goal_time_tolerance {goal_time_s:g} s is '
                          'negative')
    return traj.Tolerances(
        tuple(tables['path_position']), tuple(tables['path_velocity']),
        tuple(tables['goal_position']), tuple(tables['goal_velocity']),
        goal_time_s or defaults.goal_time_s)


class Actions:
    """The node's action servers, their node, their executor and its thread."""

    def __init__(self, host: Host) -> None:
        self._host = host
        self._log = host.get_logger()
        self._lock = threading.Lock()
        # The trajectory of each goal under way, to cancel it.
        self._runs: Dict[bytes, Any] = {}
        self.node = rclpy.create_node(f'{host.get_name()}_actions',
                                      namespace=host.get_namespace(), context=host.context)
        self._executor = SingleThreadedExecutor(context=host.context)
        self._executor.add_node(self.node)
        base = host.get_fully_qualified_name()
        self.follow_joint_trajectory = ActionServer(
            self.node, FollowJointTrajectory, f'{base}/follow_joint_trajectory',
            execute_callback=self._follow, goal_callback=lambda goal: GoalResponse.ACCEPT,
            cancel_callback=self._cancel, **_QUEUES)
        # GripperCommand: ~/<joint>/gripper_cmd for every gripper joint, and ~/gripper_cmd as
        # well when there is one (MoveIt's GripperCommand controller sends to
        # <controller>/gripper_cmd: the controller is the node, or the node's joint).
        # ParallelGripperCommand beside it, named alike: ~/<joint>/parallel_gripper_cmd and
        # ~/parallel_gripper_cmd.
        self.grippers: Dict[str, ActionServer] = {}
        joints = [joint.name for joint in host.config.joints if joint.gripper]
        for kind, leaf in ((GripperCommand, 'gripper_cmd'),
                           (ParallelGripperCommand, 'parallel_gripper_cmd')):
            names = {f'{base}/{name}/{leaf}': name for name in joints}
            if len(joints) == 1:
                names[f'{base}/{leaf}'] = joints[0]
            for action, joint in names.items():
                self.grippers[action] = ActionServer(
                    self.node, kind, action,
                    execute_callback=self._gripper_execute(joint, kind),
                    goal_callback=lambda goal: GoalResponse.ACCEPT,
                    cancel_callback=self._cancel, **_QUEUES)
        self._thread = threading.Thread(target=self._spin, name='dxl_actions', daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            self._executor.spin()
        except ExternalShutdownException:
            pass   # rclpy shut down under it: the node is going away

    def close(self) -> None:
        """Stop serving: the executor's thread ends, the node and its servers are destroyed."""
        # Goals ended by the stop still send their results (a second at most).
        deadline = time.monotonic() + 1.0
        while self._runs and time.monotonic() < deadline and self._thread.is_alive():
            time.sleep(0.01)
        self._executor.shutdown(timeout_sec=2.0)
        self._thread.join(timeout=5.0)
        self.follow_joint_trajectory.destroy()
        for server in self.grippers.values():
            server.destroy()
        self.node.destroy_node()

    # FollowJointTrajectory ------------------------------------------------------------------
    def _cancel(self, handle: Any) -> CancelResponse:
        with self._lock:
            run = self._runs.get(bytes(handle.goal_id.uuid))
        if run is None:
            return CancelResponse.REJECT
        if isinstance(run, gripper.GripperRun):
            self._host.arm.cancel_gripper_goal(run)
        else:
            self._host.arm.trajectories.cancel(run)
        return CancelResponse.ACCEPT

    def _trajectory(self, goal: Any, label: str, listener: _GoalListener) -> traj.Trajectory:
        """Return the goal as a trajectory ready to submit, or raise GoalRefused."""
        host = self._host
        if not host.active:
            raise GoalRefused(Result.INVALID_GOAL, 'the driver is not active (activate it '
                              'first): nothing moves')
        if goal.multi_dof_trajectory.joint_names or goal.multi_dof_trajectory.points:
            raise GoalRefused(Result.INVALID_JOINTS, 'multi_dof_trajectory: this driver has no '
                              'multi-DOF joints')
        arm = host.arm
        try:
            trajectory = arm.trajectory_of(goal.trajectory)
        except traj.TrajectoryJointsError as exc:
            raise GoalRefused(Result.INVALID_JOINTS, str(exc)) from None
        except BadRequest as exc:
            raise GoalRefused(Result.INVALID_GOAL, str(exc)) from None
        now_s = time.monotonic()
        if trajectory.end_s < now_s:
            raise GoalRefused(Result.OLD_HEADER_TIMESTAMP,
                              f'the trajectory ended {now_s - trajectory.end_s:.3f} s ago '
                              '(header.stamp plus its last time_from_start is in the past)')
        trajectory.tolerances = goal_tolerances(goal, trajectory.joints,
                                                arm.default_tolerances(trajectory.joints))
        trajectory.label = label
        trajectory.listener = listener
        return trajectory

    async def _follow(self, handle: Any) -> Any:
        goal_id = bytes(handle.goal_id.uuid)
        label = f'goal {goal_id.hex()[:8]}'
        channel = _Channel(self._executor)
        listener = _GoalListener(channel, 1.0 / self._host.config.action_monitor_rate)
        result = Result()
        try:
            trajectory = self._trajectory(handle.request, label, listener)
        except GoalRefused as exc:
            result.error_code, result.error_string = exc.code, str(exc)
            self._log.warning(f'follow_joint_trajectory {label} refused: {exc}')
            handle.abort()
            return result
        with self._lock:
            self._runs[goal_id] = trajectory
        self._host.arm.trajectories.submit(trajectory)
        self._log.info(f'follow_joint_trajectory {label}: {len(trajectory.points)} points over '
                       f'{trajectory.points[-1].time_s:g} s for {", ".join(trajectory.joints)}')
        try:
            while True:
                kind, payload = await channel.take()
                if kind == 'feedback':
                    handle.publish_feedback(self._feedback(trajectory, payload))
                    continue
                return self._ended(handle, payload, result)
        finally:
            with self._lock:
                self._runs.pop(goal_id, None)

    def _feedback(self, trajectory: traj.Trajectory, sample: traj.Feedback) -> Any:
        feedback = FollowJointTrajectory.Feedback()
        now = self._host.get_clock().now()
        feedback.header.stamp = now.to_msg()
        feedback.joint_names = list(sample.joints)
        since_start_s = time.monotonic() - trajectory.start_s
        feedback.desired = _point(sample.desired, sample.desired_velocity, since_start_s)
        feedback.actual = _point(sample.actual, sample.actual_velocity, since_start_s)
        feedback.error = _point(
            [d - a for d, a in zip(sample.desired, sample.actual)],
            [d - a for d, a in zip(sample.desired_velocity, sample.actual_velocity)],
            since_start_s)
        return feedback

    def _ended(self, handle: Any, outcome: traj.Outcome, result: Any) -> Any:
        how = outcome.how
        result.error_string = outcome.message or (
            f'done: final error {outcome.worst_rad:.4f} rad')
        if how == traj.SUCCEEDED:
            result.error_code = Result.SUCCESSFUL
            handle.succeed()
        elif how == traj.CANCELED and handle.is_cancel_requested:
            result.error_code = Result.SUCCESSFUL
            handle.canceled()
        else:
            result.error_code = {traj.PATH_VIOLATED: Result.PATH_TOLERANCE_VIOLATED,
                                 traj.GOAL_VIOLATED: Result.GOAL_TOLERANCE_VIOLATED}.get(
                                     how, Result.INVALID_GOAL)
            handle.abort()
        return result

    # GripperCommand and ParallelGripperCommand ------------------------------------------------
    def _gripper_execute(self, joint: str, kind: Any) -> Any:
        # A coroutine function of its own: rclpy awaits only what is one (a lambda returning a
        # coroutine would hand the coroutine over as the result).
        async def execute(handle: Any) -> Any:
            return await self._grip(handle, joint, kind)
        return execute

    async def _grip(self, handle: Any, joint: str, kind: Any) -> Any:
        goal_id = bytes(handle.goal_id.uuid)
        parallel = kind is ParallelGripperCommand
        name = 'parallel_gripper_cmd' if parallel else 'gripper_cmd'
        label = f'{name} goal {goal_id.hex()[:8]} for {joint!r}'
        channel = _Channel(self._executor)
        listener = _GoalListener(channel, 1.0 / self._host.config.action_monitor_rate)
        command = handle.request.command
        try:
            if not self._host.active:
                raise BadRequest('the driver is not active (activate it first)')
            arm = self._host.arm
            if parallel:
                run = arm.submit_parallel_gripper_goal(joint, command, listener)
            else:
                run = arm.submit_gripper_goal(joint, command.position, command.max_effort,
                                              listener)
        except BadRequest as exc:
            # Neither action's result has an error field: the log says why.
            self._log.warning(f'{label} refused: {exc}')
            handle.abort()
            return kind.Result()
        with self._lock:
            self._runs[goal_id] = run
        try:
            while True:
                event, payload = await channel.take()
                if event == 'feedback':
                    feedback = kind.Feedback()
                    self._fill_gripper(feedback, joint, payload)
                    handle.publish_feedback(feedback)
                    continue
                return self._gripper_ended(handle, label, joint, kind, payload)
        finally:
            with self._lock:
                self._runs.pop(goal_id, None)

    def _gripper_ended(self, handle: Any, label: str, joint: str, kind: Any,
                       outcome: gripper.GripperOutcome) -> Any:
        result = kind.Result()
        if outcome.sample is not None:
            self._fill_gripper(result, joint, outcome.sample)
        if outcome.how in (gripper.REACHED, gripper.STALLED):
            # A stall on an object is what closing on it is for: succeeded, stalled and not
            # reached_goal say so (gripper_action_controller's allow_stalling: true; MoveIt's
            # ParallelGripperCommand handle on Jazzy judges by the status alone).
            self._log.info(f'{label}: {outcome.message}')
            handle.succeed()
        elif outcome.how == gripper.CANCELED and handle.is_cancel_requested:
            handle.canceled()
        else:
            self._log.warning(f'{label} ended: {outcome.message}')
            handle.abort()
        return result

    def _fill_gripper(self, message: Any, joint: str, sample: gripper.GripperSample) -> None:
        """Fill a feedback or result: GripperCommand's fields, or ParallelGripperCommand's."""
        if hasattr(message, 'position'):
            message.position = float(sample.position)
            message.effort = float(sample.effort)
        else:
            state = message.state
            state.header.stamp = self._host.get_clock().now().to_msg()
            state.name = [joint]
            state.position = [float(sample.position)]
            state.velocity = [float(sample.velocity)]
            state.effort = [float(sample.effort)]
        if hasattr(message, 'stalled'):   # not in ParallelGripperCommand's feedback
            message.stalled = bool(sample.stalled)
            message.reached_goal = bool(sample.reached_goal)
