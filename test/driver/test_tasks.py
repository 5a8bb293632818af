"""The task runner: steps round-robin within a budget, and a waiting task is left alone."""

from typing import List

from dxl_servo_driver.driver.tasks import Steps, Task, TaskRunner


class Clock:
    """A clock the test moves: each read advances it by `tick` (a step takes time)."""

    def __init__(self, tick: float = 0.0) -> None:
        self.now = 100.0
        self.tick = tick

    def __call__(self) -> float:
        self.now += self.tick
        return self.now


def booting(clock: Clock, log: List[str], boot_s: float) -> Steps:
    log.append('reboot sent')
    yield
    wake_s = clock.now + boot_s
    yield wake_s   # nothing to ask before the servo has booted
    log.append(f'ping at {clock.now - wake_s:+.3f}')


def test_a_waiting_task_is_not_stepped_before_its_time() -> None:
    clock = Clock()
    log: List[str] = []
    runner = TaskRunner(clock)
    runner.add(Task('gripper', 'reboot', booting(clock, log, boot_s=1.0)))
    # A cycle with 5 ms to spare: the task sends its reboot, says when it wakes, and the
    # runner returns at once instead of stepping it round until the budget is spent.
    assert runner.run(clock.now + 0.005) == (2, [])
    assert log == ['reboot sent']
    for _ in range(99):   # 99 cycles of 10 ms: still booting, not a single step
        clock.now += 0.01
        assert runner.run(clock.now + 0.005) == (0, [])
    clock.now += 0.01
    steps, ended = runner.run(clock.now + 0.005)
    assert steps == 1 and [(task.joint, error) for task, error in ended] == [('gripper', None)]
    assert log == ['reboot sent', 'ping at +0.000'] and 'gripper' not in runner


def test_steps_share_the_budget_round_robin() -> None:
    clock = Clock(tick=0.001)
    order: List[str] = []

    def work(name: str) -> Steps:
        for _ in range(100):
            order.append(name)
            yield

    runner = TaskRunner(clock)
    runner.add(Task('a', 'restore', work('a')))
    runner.add(Task('b', 'restore', work('b')))
    steps, ended = runner.run(clock.now + 0.010)
    assert ended == []
    assert 3 <= steps <= 6
    assert order[:4] == ['a', 'b', 'a', 'b']


def test_run_to_end_sleeps_through_a_wait() -> None:
    clock = Clock()
    log: List[str] = []
    task = Task('gripper', 'reboot', booting(clock, log, boot_s=0.02))

    def real_time() -> float:
        clock.now += 0.001   # the clock runs while the caller sleeps
        return clock.now

    task.run_to_end(real_time)
    assert task.done and log[0] == 'reboot sent'
    assert float(log[1].split()[-1]) >= 0.0   # pinged once booted, not before
