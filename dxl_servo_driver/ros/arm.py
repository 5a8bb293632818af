"""
The arm's side of the node: trajectories run in the cycle, joint-state and gripper commands.

What an arm asks of the driver beyond one servo's goal: a JointTrajectory sampled at every
cycle (trajectory.Executor), a sensor_msgs/JointState command with each joint's value taken by
its mode (what ros2_control's topic bridge publishes), a gripper goal with its current, and
whether each gripper holds something. Each request is answered with a Result: the node's
subscriptions log its reason when refused. No bus work here: goals go to the manager's queue,
written by the next cycle.
"""

import math
import threading
import time
from typing import Any, Dict, List, Optional, Protocol, Sequence, Tuple

from dxl_servo_driver import config as cfg
from dxl_servo_driver.arm import gripper
from dxl_servo_driver.arm import trajectory as traj
from dxl_servo_driver.arm.commands import split_joint_state
from dxl_servo_driver.arm.gripper import GraspDetector, gripper_goal, GripperError, GripperSpec
from dxl_servo_driver.driver.manager import IDX_EFFORT, IDX_POSITION, IDX_VELOCITY, Manager, Result
from dxl_servo_driver.errors import BadRequest
from dxl_servo_driver.models import modes

__all__ = ['Arm']


class Host(Protocol):
    """What the arm needs of the node."""

    manager: Manager
    config: cfg.DriverConfig

    def get_logger(self) -> Any:
        """Return the node's logger (rclpy Node)."""

    def get_clock(self) -> Any:
        """Return the node's clock (rclpy Node): trajectory stamps are on it."""


class Arm:
    """Trajectories, joint-state and gripper commands, grasps: one per node."""

    def __init__(self, host: Host, config: cfg.DriverConfig) -> None:
        self._host = host
        self.trajectories = traj.Executor(self._present_rad, self._trajectory_ended,
                                          config.goal_tolerance)
        self.grasps: Dict[str, GraspDetector] = {}
        self.gripper_runs: Dict[str, gripper.GripperRun] = {}
        self._gripper_lock = threading.Lock()
        self.take(config)

    def take(self, config: cfg.DriverConfig) -> None:
        """Take a new configuration's grippers (configure after parameters changed)."""
        self.grasps = {joint.name: GraspDetector(joint.ratio) for joint in config.joints
                       if joint.gripper}

    # trajectories ---------------------------------------------------------------------------
    def _present_rad(self, name: str) -> Optional[float]:
        # The last position read, fresh or not: where a joint holds when a trajectory ends.
        servo = self._host.manager.servos.get(name)
        if servo is None or servo.state is None:
            return None
        return servo.position_rad(servo.state[IDX_POSITION])

    def _sense(self, name: str) -> Optional[Tuple[float, float]]:
        # This cycle's sample only: tolerances and feedback never judge a stale one.
        servo = self._host.manager.servos.get(name)
        if servo is None or servo.state is None or not servo.fresh:
            return None
        state = servo.state
        return (servo.position_rad(state[IDX_POSITION]),
                servo.units.velocity_to_rad_s(state[IDX_VELOCITY]))

    def limits(self) -> Dict[str, traj.Limits]:
        """Return what a trajectory is checked against: each joint's mode and range (rad)."""
        limits = {}
        for servo in self._host.manager.joints:
            low, high = servo.joint_position_range()
            limits[servo.name] = traj.Limits(servo.mode, low, high, servo.online)
        return limits

    def trajectory_of(self, msg: Any, now_s: Optional[float] = None) -> traj.Trajectory:
        """
        Return a JointTrajectory validated whole, starting at its stamp (now if unstamped).

        Raises TrajectoryError (TrajectoryJointsError for its joints) saying what is wrong.
        """
        servos = self._host.manager.servos
        for name in msg.joint_names:
            # A passive joint or a trigger is refused by name, before anything is checked.
            refusal = servos[name].joint.refusal() if name in servos else ''
            if refusal:
                raise traj.TrajectoryJointsError(refusal)
        points = [traj.Point(p.time_from_start.sec + p.time_from_start.nanosec * 1e-9,
                             tuple(p.positions), tuple(p.velocities)) for p in msg.points]
        start_s = time.monotonic() if now_s is None else now_s
        stamp = msg.header.stamp
        if stamp.sec or stamp.nanosec:
            # The stamp is on the node's clock: the same distance from now on the cycle's.
            now_ns = self._host.get_clock().now().nanoseconds
            start_s += (stamp.sec * 10 ** 9 + stamp.nanosec - now_ns) * 1e-9
        for name in msg.joint_names:
            # A joint another commander holds (a follower's) is refused whole, with why.
            held = self._host.manager.holder(name)
            if held:
                raise traj.TrajectoryJointsError(held)
        return traj.validate(list(msg.joint_names), points, self.limits(), start_s)

    def default_tolerances(self, joints: Sequence[str]) -> traj.Tolerances:
        """Return the tolerances the parameters give these joints (path, goal, goal time)."""
        config = self._host.config
        zeros = (0.0,) * len(joints)
        return traj.Tolerances(
            tuple(config.joint(name).path_tolerance for name in joints), zeros,
            tuple(config.joint(name).goal_tolerance or config.goal_tolerance for name in joints),
            zeros, config.goal_time_tolerance)

    def submit_trajectory(self, msg: Any) -> Result:
        """Validate a JointTrajectory whole and start it at its stamp (now if unstamped)."""
        try:
            trajectory = self.trajectory_of(msg)
        except BadRequest as exc:
            return Result(False, str(exc))
        trajectory.label = 'a ~/joint_trajectory message'
        trajectory.tolerances = self.default_tolerances(trajectory.joints)
        self.trajectories.submit(trajectory)
        return Result(True, f'trajectory of {len(trajectory.points)} points accepted')

    def prepare_goals(self, now_s: float) -> None:
        """Queue this cycle's trajectory and gripper goals (the cycle, before its write)."""
        if self.gripper_runs:
            self._walk_grippers(now_s)
        manager = self._host.manager
        goals = self.trajectories.step(now_s, self._sense, manager.joint_trouble)
        if not goals:
            return
        result = manager.command('position', list(goals), list(goals.values()))
        if not result.success:
            # Whatever refused them (the trouble check ends the usual cases first), the rest of
            # the path is not run blind.
            self.trajectories.cancel(why=f'its goals were refused: {result.message}')

    def cancel(self, why: str = 'the bus cycle stopped') -> None:
        """End every trajectory and gripper goal as aborted (deactivate, error, shutdown)."""
        self.trajectories.cancel(why=why)
        self._end_gripper_goals(why)

    def _trajectory_ended(self, outcome: traj.Outcome) -> None:
        log = self._host.get_logger()
        if outcome.how == traj.SUCCEEDED:
            log.info(f'trajectory done (final error {outcome.worst_rad:.4f} rad)')
        elif outcome.how in (traj.PREEMPTED, traj.CANCELED):
            log.info(f'trajectory {outcome.message}')
        else:
            log.warning(f'trajectory ended: {outcome.message}')

    # commands -------------------------------------------------------------------------------
    def _queue_all(self, goals: List[Tuple[str, List[str], List[float]]]) -> Result:
        """Queue (kind, joints, values) goals in order: all checked first, then all or none."""
        manager = self._host.manager
        for kind, joints, values in goals:
            checked = manager.check_goals(kind, joints, values)
            if not checked.success:
                return checked
        for kind, joints, values in goals:
            result = manager.command(kind, joints, values)
            if not result.success:
                return result
        return Result(True, 'queued')

    def joint_command(self, msg: Any) -> Result:
        """Queue a sensor_msgs/JointState command, each joint's value taken by its mode."""
        servos = self._host.manager.servos
        try:
            goals = split_joint_state(
                list(msg.name), {'position': msg.position, 'velocity': msg.velocity,
                                 'effort': msg.effort},
                {name: servo.mode for name, servo in servos.items()},
                # Through the joint's frame: a reversed or geared joint's effort is not the
                # servo's torque.
                {name: servo.units.joint_nm_per_a for name, servo in servos.items()})
        except BadRequest as exc:
            return Result(False, str(exc))
        return self._queue_all([(kind, joints, values)
                                for kind, (joints, values) in goals.items()])

    def gripper_command(self, msg: Any) -> Result:
        """Queue a gripper goal and the current it may close with."""
        servo = self._host.manager.servos.get(msg.name)
        if servo is None:
            return Result(False, f'unknown joint {msg.name!r}')
        if not servo.joint.gripper:
            return Result(False, f'joint {msg.name!r} is not a gripper (set {msg.name}.gripper: '
                          'true)')
        if servo.mode != 'current_based_position':
            return Result(False, f'gripper {msg.name!r} is in {servo.mode} mode, not '
                          'current_based_position')
        limit = servo.units.current_to_a(servo.limits.get('current_limit', 0))
        spec = GripperSpec(servo.name, servo.joint.gripper_open, servo.joint.gripper_closed,
                           limit)
        try:
            goal, current = gripper_goal(spec, msg.position, msg.ratio, msg.max_effort)
        except BadRequest as exc:
            return Result(False, str(exc))
        # The current first: a gripper never closes with more than it was told.
        goals = [('current', [servo.name], [current])] if current is not None else []
        return self._queue_all(goals + [('position', [servo.name], [goal])])

    # gripper goals (the GripperCommand and ParallelGripperCommand actions) ----------------
    def submit_gripper_goal(self, name: str, position: float, max_effort_nm: float,
                            listener: gripper.GripperListener, speed: float = 0.0,
                            effort_field: str = 'max_effort') -> gripper.GripperRun:
        """
        Queue a gripper goal and watch it; raise GripperError saying why not.

        position in rad, max_effort_nm the effort limit in N*m (0: the configured goal
        current), speed the most rad/s on the way (0: the servo's own profile), effort_field
        the name of the effort in refusals. A goal under way on the joint is preempted.
        """
        manager = self._host.manager
        if not math.isfinite(max_effort_nm) or max_effort_nm < 0.0:
            raise GripperError(f'{effort_field} {max_effort_nm} N*m is not a finite effort '
                               '>= 0')
        servo = self._gripper_servo(name, max_effort_nm, effort_field)
        torque_constant = abs(servo.units.joint_nm_per_a)   # max_effort is a magnitude
        current = max_effort_nm / torque_constant if max_effort_nm > 0.0 else math.nan
        spec = GripperSpec(servo.name, servo.joint.gripper_open, servo.joint.gripper_closed,
                           servo.units.current_to_a(servo.limits.get('current_limit', 0)))
        try:
            goal, current_a = gripper_goal(spec, position, math.nan, current)
        except GripperError as exc:
            # Said in the action's unit, N*m, not the current it was turned into.
            raise GripperError(str(exc).replace(
                f'max_effort {current:g} A', f'{effort_field} {max_effort_nm:g} N*m '
                f'({current:g} A at {torque_constant:g} N*m/A)')) from None
        checked = manager.check_goals('position', [name], [goal])
        if not checked.success:
            raise GripperError(checked.message)
        start = self._walk_start(servo, goal, speed)
        first = goal if start is None else start
        goals = [('current', [name], [current_a])] if current_a is not None else []
        tolerance = servo.joint.goal_tolerance or self._host.config.goal_tolerance
        # Queued and filed under one lock: a walk step of the goal this one preempts is
        # never queued after this goal's own. (Only the goal queue's lock is taken inside:
        # the cycle takes this one with the manager's lock held.)
        with self._gripper_lock:
            first_raw = checked.value[0][2]
            if start is not None:
                stepped = manager.check_goals('position', [name], [start])
                if not stepped.success:
                    raise GripperError(stepped.message)
                first_raw = stepped.value[0][2]
            queued = self._queue_all(goals + [('position', [name], [first])])
            if not queued.success:
                raise GripperError(queued.message)
            run = gripper.GripperRun(name, goal, first_raw, tolerance, listener,
                                     time.monotonic(), servo.joint.ratio, start, speed)
            old = self.gripper_runs.get(name)
            self.gripper_runs[name] = run
        if old is not None:
            old.listener.ended(gripper.GripperOutcome(
                gripper.PREEMPTED, f'preempted by a new gripper goal for {name!r}', old.last))
        return run

    def submit_parallel_gripper_goal(self, name: str, command: Any,
                                     listener: gripper.GripperListener) -> gripper.GripperRun:
        """
        Queue a ParallelGripperCommand's command (a sensor_msgs/JointState) for joint name.

        Raises GripperError saying why not (gripper.parallel_command, submit_gripper_goal).
        """
        position, speed, effort = gripper.parallel_command(
            name, list(command.name), list(command.position), list(command.velocity),
            list(command.effort))
        return self.submit_gripper_goal(name, position, effort, listener, speed=speed,
                                        effort_field='command.effort')

    def _walk_start(self, servo: Any, goal: float, speed: float) -> Optional[float]:
        """Return where a goal with a speed starts its walk (None: no speed, go at once)."""
        if speed <= 0.0:
            return None
        if not math.isfinite(speed):
            raise GripperError(f'speed {speed} is not a finite speed >= 0')
        if servo.state is None:
            raise GripperError(f'no position of {servo.name!r} read yet: a goal with a '
                               'velocity walks from it')
        # From the present position, within the travel (a hand may have pushed it past).
        low, high = sorted((servo.joint.gripper_open, servo.joint.gripper_closed))
        return min(high, max(low, servo.position_rad(servo.state[IDX_POSITION])))

    def _walk_grippers(self, now_s: float) -> None:
        """Queue this cycle's step of each gripper goal walked at its speed."""
        manager = self._host.manager
        refused = []
        with self._gripper_lock:
            for run in self.gripper_runs.values():
                setpoint = run.next_setpoint(now_s)
                if setpoint is None:
                    continue
                checked = manager.check_goals('position', [run.joint], [setpoint])
                result = (manager.command('position', [run.joint], [setpoint])
                          if checked.success else checked)
                if result.success:
                    run.queued(checked.value[0][2])
                else:
                    refused.append((run, result.message))
            for run, _ in refused:
                del self.gripper_runs[run.joint]
        for run, why in refused:
            run.listener.ended(gripper.GripperOutcome(
                gripper.ABORTED, f'its next step was refused: {why}', run.last))

    def _gripper_servo(self, name: str, effort_nm: float = 0.0,
                       effort_field: str = 'max_effort') -> Any:
        servo = self._host.manager.servos.get(name)
        if servo is None:
            raise GripperError(f'unknown joint {name!r}')
        if not servo.joint.gripper:
            raise GripperError(f'joint {name!r} is not a gripper (set {name}.gripper: true)')
        if servo.mode != 'current_based_position':
            if effort_nm > 0.0 and 'current' not in modes.BY_NAME[servo.mode].commands:
                raise GripperError(
                    f'{effort_field} {effort_nm:g} N*m needs current control: gripper '
                    f'{name!r} is in {servo.mode} mode, which has none (only '
                    'current_based_position limits the current it closes with)')
            raise GripperError(f'gripper {name!r} is in {servo.mode} mode, not '
                               'current_based_position')
        return servo

    def cancel_gripper_goal(self, run: gripper.GripperRun) -> None:
        """Ask a gripper goal to end; the next cycle holds the gripper where it is."""
        run.cancel_requested = True

    def watch_grippers(self, now_s: float) -> None:
        """Watch every gripper goal on this cycle's sample (called by the cycle)."""
        manager = self._host.manager
        with self._gripper_lock:
            runs = list(self.gripper_runs.items())
        for name, run in runs:
            servo = manager.servos[name]
            state = servo.state
            position = velocity = effort = None
            if state is not None and servo.fresh:
                units = servo.units
                position = servo.position_rad(state[IDX_POSITION])
                velocity = units.velocity_to_rad_s(state[IDX_VELOCITY])
                effort = units.effort_to_nm(state[IDX_EFFORT])
            detector = self.grasps.get(name)
            outcome = run.watch(now_s, position, velocity or 0.0, effort or 0.0,
                                detector is not None and detector.grasping,
                                servo.goal_raw.get('goal_position'), manager.joint_trouble(name))
            if outcome is None:
                continue
            with self._gripper_lock:
                if self.gripper_runs.get(name) is run:
                    del self.gripper_runs[name]
            if outcome.how in (gripper.CANCELED, gripper.STOPPED_SHORT) and state is not None:
                # Held where it is, not pushed on toward a goal it is not going to.
                manager.command('position', [name], [servo.position_rad(state[IDX_POSITION])])
            run.listener.ended(outcome)

    def _end_gripper_goals(self, why: str) -> None:
        with self._gripper_lock:
            runs = list(self.gripper_runs.values())
            self.gripper_runs.clear()
        for run in runs:
            run.listener.ended(gripper.GripperOutcome(gripper.ABORTED, why, run.last))

    # grasps -----------------------------------------------------------------------------------
    def update_grasps(self, now_s: float) -> None:
        """Judge from this cycle's sample whether each gripper holds something; log changes."""
        for name, detector in self.grasps.items():
            servo = self._host.manager.servos[name]
            state = servo.state
            goal_position = servo.goal_raw.get('goal_position')
            goal_current = servo.goal_raw.get('goal_current')
            if state is None or not servo.fresh or goal_position is None or goal_current is None:
                continue
            units = servo.units
            was = detector.grasping
            held = detector.update(
                now_s, servo.position_rad(state[IDX_POSITION]),
                units.velocity_to_rad_s(state[IDX_VELOCITY]),
                units.current_to_a(state[IDX_EFFORT]),
                servo.position_rad(goal_position), units.current_to_a(goal_current))
            if held != was:
                self._host.get_logger().info(f'gripper {name!r}: ' + (
                    'holding an object' if held else 'no longer holding an object'))

    def idle(self) -> bool:
        """Return True when the cycle has nothing to prepare: no trajectory, no gripper goal."""
        return not self.gripper_runs and not self.trajectories.busy

    def watch_samples(self, read_ok: bool) -> None:
        """Judge this cycle's samples: grasps, gripper goals (the cycle, before publishing)."""
        if read_ok and self.grasps:
            self.update_grasps(time.monotonic())
        if self.gripper_runs:
            self.watch_grippers(time.monotonic())

    def grasping(self) -> Dict[str, bool]:
        """Return whether each gripper holds something."""
        return {name: detector.grasping for name, detector in self.grasps.items()}

    def facts(self) -> Dict[str, Any]:
        """Return the arm's lines of /diagnostics (trajectories taken, ended, their error)."""
        executor = self.trajectories
        last = executor.last_outcome
        return {'trajectories_accepted': executor.accepted,
                'trajectories_finished': executor.finished,
                'trajectories_beyond_goal_tolerance': executor.out_of_tolerance,
                'last_trajectory_final_error_rad':
                    f'{last.worst_rad:.4f}' if last is not None else 'none'}
