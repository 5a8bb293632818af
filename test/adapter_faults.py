"""
Test helper: the misbehaving adapter, under the name the tests import it by.

It lives in the simulator package (dxl_servo_driver/sim/adapter_faults.py), where virtual_bus
holds one too (its `adapter ...` console commands); the tests' names are re-exported here.
"""

from dxl_servo_driver.sim.adapter_faults import (  # noqa: F401 - re-exported
    AdapterProxy, FaultEngine, Faults, FaultStats, FaultyPort, Framing, FRAMINGS, HEAD, IDLE_S,
    LATE_HISTORY, PARTIAL_FLUSH_S, POLL_S, RawPort, READ_CHUNK, WRITE_TIMEOUT_S)
