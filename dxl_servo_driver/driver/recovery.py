"""
Getting servos back: restarts, reboots, hardware errors, servos lost with the adapter.

A servo that restarted on its own (power cut, brown-out), was rebooted, or lost power with the
adapter gets its configuration back step by step, as a task the cycle steps in the time it has
left, so it never stalls the others; it then holds where it is, its lost whole turns kept. A
failed restore is tried again until it works. A lost port stops the cycle's bus work (the node
stays up) until the adapter comes back; every servo then rejoins on its own.
"""

from typing import List, Optional

from dxl_servo_driver.driver.context import Context
from dxl_servo_driver.driver.cycle import Cycle
from dxl_servo_driver.driver.goals import Goals
from dxl_servo_driver.driver.servo import IDX_HW_ERROR, Servo, Throttle
from dxl_servo_driver.driver.setup import Setup
from dxl_servo_driver.driver.tasks import Steps, Task
from dxl_servo_driver.errors import CommTimeout, CorruptReply, PortError, StatusError
from dxl_servo_driver.models import modes

BOOT_TIMEOUT_S = 3.0      # a rebooted servo must answer a ping within this
BOOT_POLL_S = 0.02        # between two pings of a booting servo
RETRY_BACKOFF_S = 0.5     # a failed restore is tried again after this
# The tasks that end with the servo set up again and holding (cut short, they are done again).
RESTORING_TASKS = ('restore', 'reboot', 'recover')
REJOIN_INTERVAL_S = 1.0   # a servo missing after the adapter came back is probed this often


class Recovery:
    """The restore, reboot and rejoin tasks, and what their outcome means."""

    def __init__(self, ctx: Context, setup: Setup, goals: Goals, cycle: Cycle) -> None:
        self._ctx = ctx
        self._roster = ctx.roster
        self._link = ctx.link
        self._setup = setup
        self._goals = goals
        self._cycle = cycle
        self._tasks = ctx.tasks
        self._port = ctx.port
        self._clock = ctx.clock
        self._log = ctx.log
        self._warn_throttled = Throttle(ctx.log.warn, clock=ctx.clock)
        self.recoveries = 0

    # the steps ------------------------------------------------------------------------------
    def restarted(self, servo: Servo) -> None:
        """Restore a servo that restarted on its own (power cut, brown-out), step by step."""
        if servo.name in self._tasks:
            return
        # The task first: whoever sees the restart counted (another thread) sees it restoring.
        self.start(servo, 'restore', self.restore(servo, servo.last_joint_pulses()))
        servo.restarts += 1
        self._log.warn(f'joint {servo.name!r} (id {servo.servo_id}) restarted on its own: '
                       f'restoring its configuration and mode; {_afterwards(servo)}')

    def restore(self, servo: Servo, last_joint_pulses: Optional[int]) -> Steps:
        """
        Give a restarted servo its setup back and make it hold where it is.

        The servo's RAM is back to its defaults and its position was re-initialised within one
        turn: the configuration is written again, the lost whole turns go into the joint's turn
        offset (assuming the horn moved less than half a turn while it was down), and it holds
        where it is (goal = present; velocity, current and PWM goals 0): a goal nobody sent
        again is never replayed, a wheel does not start turning again by itself.
        """
        servo.tick.reset()
        servo.status = 'restoring'
        yield from self._setup.apply_configuration(servo)
        present = self._link.read(servo, 'present_position')
        yield
        if servo.mode in modes.SINGLE_TURN:
            servo.turn_offset = 0
        elif last_joint_pulses is not None:
            servo.turn_offset = servo.units.kept_turns(last_joint_pulses, present)
        for register in list(servo.goal_raw):
            if register != 'goal_current' or servo.mode != 'current_based_position':
                del servo.goal_raw[register]
        yield from self._setup.hold(servo)
        servo.status = ''
        servo.restore_due = False

    def reboot(self, servo: Servo) -> Steps:
        """REBOOT one servo, wait for it to boot, give it its setup back holding where it is."""
        servo.status = 'rebooting'
        last = servo.last_joint_pulses()
        link = self._link
        try:
            last = servo.joint_pulses(link.read(servo, 'present_position'))
            yield
        except (CommTimeout, CorruptReply, StatusError):
            pass   # a servo in trouble may not answer reads: the last good state will do
        servo.torque_maybe_on = False   # a reboot clears torque enable
        link.reboot(servo)
        servo.tick.reset()   # its Realtime Tick starts again from 0
        yield
        deadline = self._clock() + BOOT_TIMEOUT_S
        next_ping = self._clock() + BOOT_POLL_S
        while True:
            if self._clock() < next_ping:
                yield next_ping   # booting: nothing to ask before then
            try:
                link.ping_once(servo)
                break
            except CommTimeout:
                if self._clock() > deadline:
                    raise CommTimeout(f'id {servo.servo_id}: did not answer within '
                                      f'{BOOT_TIMEOUT_S:g} s of its reboot', servo.servo_id)
                next_ping = self._clock() + BOOT_POLL_S
                yield
        yield from self.restore(servo, last)

    def rejoin(self, servo: Servo) -> Steps:
        """After the adapter came back: find the servo, restore it if it lost power."""
        servo.status = 'not answering since the adapter came back'
        self._link.ping_once(servo)
        yield
        values = self._link.read_block(servo)
        yield
        servo.status = ''
        restarted = servo.block.restarted(values)
        if not restarted and not servo.restore_due:
            servo.tick.reset()
            return   # it kept its power and its setup: it holds what it held
        if restarted:
            servo.restarts += 1
        yield from self.restore(servo, servo.last_joint_pulses())

    # the tasks ------------------------------------------------------------------------------
    def start(self, servo: Servo, kind: str, steps: Steps, not_before_s: float = 0.0) -> Task:
        """Start a task on a servo: out of the cycle's read, its queued goals dropped."""
        servo.fresh = False
        self._goals.drop(servo)
        task = self._tasks.add(Task(servo.name, kind, steps, not_before_s))
        self._cycle.refresh()
        return task

    def ended(self, task: Task, error: Optional[Exception]) -> None:
        """Take a task that ended: done, or failed (a lost port propagates to the cycle)."""
        if error is None:
            self.task_done(task)
        else:
            self.task_failed(task, error)

    def task_done(self, task: Task) -> None:
        """Take a servo that finished its task back into the cycle."""
        servo = self._roster.by_name[task.joint]
        servo.status = ''
        self._cycle.want_full()
        self._cycle.refresh()
        if task.kind == 'restore':
            self._log.info(f'joint {servo.name!r}: restored after its restart; '
                           f'{_afterwards(servo, done=True)}')
        elif task.kind == 'recover':
            servo.health_time = 0.0
            self._log.info(f'joint {servo.name!r}: recovered, ' + (
                'configuration and torque restored' if servo.joint.torque else
                f'configuration restored; {_afterwards(servo, done=True)}'))
        elif task.kind == 'rejoin':
            self._log.info(f'joint {servo.name!r}: answering again')

    def task_failed(self, task: Task, exc: Exception) -> None:
        """Try a failed restore or probe again later; a lost port propagates to the cycle."""
        servo = self._roster.by_name[task.joint]
        if isinstance(exc, PortError):
            raise exc
        if task.kind == 'reboot':
            servo.status = ''
            self._cycle.refresh()
            return   # the service that asked reports it
        # Restores and probes are tried again until they work: the servo is of no use before.
        retry = REJOIN_INTERVAL_S if task.kind == 'rejoin' else RETRY_BACKOFF_S
        self._warn_throttled(f'task:{servo.name}',
                             f'joint {servo.name!r}: {task.kind} failed ({exc}); trying again')
        steps = (self.rejoin(servo) if task.kind == 'rejoin'
                 else self.restore(servo, servo.last_joint_pulses()))
        self.start(servo, task.kind if task.kind != 'recover' else 'restore', steps,
                   self._clock() + retry)

    def recover_hardware_errors(self) -> None:
        """With hardware_error_recovery: reboot a faulty servo alone, rate-limited, restored."""
        if not self._ctx.config.hardware_error_recovery:
            return
        now = self._clock()
        for servo in self._roster.active():
            state = servo.state
            if (not servo.health_time or state is None or not state[IDX_HW_ERROR]
                    or servo.name in self._tasks):
                continue
            if now - servo.last_recovery_s < self._ctx.config.recovery_interval:
                continue
            servo.last_recovery_s = now
            servo.recoveries += 1
            self.recoveries += 1
            errors = ', '.join(servo.model.decode_hardware_errors(state[IDX_HW_ERROR]))
            self._log.warn(f'joint {servo.name!r} (id {servo.servo_id}): hardware error '
                           f'{errors}: rebooting it to recover (recovery {servo.recoveries})')
            self.start(servo, 'recover', self.reboot(servo))

    def start_reboots(self, servos: List[Servo]) -> List[Task]:
        """Start a reboot task for each servo."""
        return [self.start(servo, 'reboot', self.reboot(servo)) for servo in servos]

    def run_to_end(self, tasks: List[Task]) -> None:
        """Run tasks here to their end (nobody else steps them); failures stay in task.error."""
        for task in tasks:
            if not task.done:
                try:
                    task.run_to_end(self._clock)
                except Exception:  # noqa: B902 - reported from task.error by the caller
                    pass
                self._tasks.cancel_all('done', [task.joint])
        self._cycle.refresh()

    def restore_later(self, servo: Servo) -> None:
        """Restore in the background a servo a failed reboot may have left unconfigured."""
        if servo.name not in self._tasks and not self._port.lost:
            self.start(servo, 'restore', self.restore(servo, servo.last_joint_pulses()),
                       self._clock() + RETRY_BACKOFF_S)


def _afterwards(servo: Servo, done: bool = False) -> str:
    """Return what a restored servo does: holds, stays passive, or springs back (a trigger)."""
    if not servo.joint.torque:
        return 'passive (torque: false), never torqued'
    if servo.joint.trigger:
        return 'a trigger, its spring re-armed' if done else 'its trigger springs back to its rest'
    if not servo.torque_wanted:   # torque_on_start false, or turned off: it stays off
        return 'torque off, as it was'
    return 'holding where it is' if done else 'it will hold where it is'
