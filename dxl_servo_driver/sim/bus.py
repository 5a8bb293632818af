"""
The simulated servos on one bus: bytes in, status packets out, plus fault injection.

One StreamParser sees the host's bytes; each whole packet goes to every powered, plugged servo
listening at the baud the bytes came at.  Replies come back in wire order: for SYNC_READ the
order of the ids in the packet, for BULK_READ the order of its records, for a broadcast PING
ascending id; FAST_SYNC_READ and FAST_BULK_READ parts are framed into one status packet in the
order asked (a Fast Bulk Read's parts each of its own record's length). Fault injection acts
per servo object (found by its current id): a dropped status is lost, a corrupted one has one
bit flipped after the header so the receiver's CRC check fails (CRC-16 catches every
single-bit error); in a fast read that is the servo's part.

Every byte goes to two receivers, a Protocol 2.0 and a Protocol 1.0 StreamParser: each servo
hears the packets of the protocol its Protocol Version register names (sim/protocol1.py answers
1.0); for a 1.0 BULK_READ the replies come in the order of its records. A corrupted 1.0 status
has its bit flipped after the header, id and length, so its checksum fails.

Each servo is of one model (models.Model, the XM430 manual's 1030 unless `models` says
otherwise): its control table, its ping answer, its hardware error bits and its physics.

Several servos may share an id (the factory state: every new servo is id 1). A servo is named by
a ServoRef: its id, when exactly one servo of the bus has it (plugged or not), or '#N', the N-th
servo given to the bus (1-based), which stays that servo whatever its id becomes. Servos that
answer one request at the same place in the wire order (the same id twice) collide: their
replies are combined as the line combines them (sim/collision.py), so the host reads garbled
bytes, never one clean reply; in a fast read the colliding parts are combined inside the one
packet.

A hand may turn a servo's horn while its torque is off (turn), and mechanical end stops may
bound the horn (set_stops): both in servo radians, as the driver reports a servo with no
offset, no reverse and a ratio of 1 (Present Position = the model's zero + rad / rad per pulse).
"""

from dataclasses import dataclass
import random
import threading
import time
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence, Union

from dxl_servo_driver.models import Model
from dxl_servo_driver.protocol import (
    BROADCAST_ID, encode_fast_status, FAST_HEAD_SIZE, Instruction, MAX_ID, Packet, ParseEvent,
    StreamParser)
from dxl_servo_driver.protocol.protocol1 import StreamParser1
from dxl_servo_driver.sim import protocol1
from dxl_servo_driver.sim.collision import BITS_PER_FRAME, SKEW_BITS, wired_and
from dxl_servo_driver.sim.dynamics import ServoDynamics
from dxl_servo_driver.sim.memory import MANUAL_MODEL
from dxl_servo_driver.sim.servo import SimServo

# The words of inject_error (and of the console's `error ID KIND`, README.md) and the Hardware
# Error Status bit each one latches, by the model's name for it (models.Model.hardware_error_bits
# has the bit values).
ERROR_KINDS: dict[str, str] = {
    'overload': 'overload', 'overheat': 'overheating', 'voltage': 'input_voltage',
    'encoder': 'motor_encoder', 'shock': 'electrical_shock',
}
# A servo on the bus: its id (when only one servo has it), or '#N', the N-th servo given (1-based).
ServoRef = Union[int, str]
# How long a hand takes for a turn unless told (s).
TURN_SECONDS = 0.5
# Replies of one packet stay in wire order; servos answering at the same rank collide.
_LAST = 1 << 16
_FAST_READS = (Instruction.FAST_SYNC_READ, Instruction.FAST_BULK_READ)


@dataclass(frozen=True)
class Reply:
    """A status packet as it goes on the wire."""

    data: bytes
    servo_id: int
    return_delay_s: float
    flip_bit: int = -1   # a fast read's part: the bit corrupted once framed (-1: none)


class _Slot:
    """One servo on the bus and its fault-injection state."""

    def __init__(self, servo: SimServo) -> None:
        self.servo = servo
        self.plugged = True
        self.drop_probability = 0.0
        self.corrupt_probability = 0.0


class SimBus:
    """Simulated servos sharing one bus."""

    def __init__(self, ids: Iterable[int], clock: Callable[[], float] = time.monotonic,
                 seed: int | None = None, boot_time_s: float = 0.1,
                 models: Mapping[int, Model] | Sequence[Model] | None = None,
                 firmware: Mapping[int, int] | Sequence[int | None] | None = None) -> None:
        """
        Put servos with these ids on the bus, in this order (an id may repeat).

        models maps an id to its servo's model (the others are the XM430 manual's, 1030), or
        lists one model per servo, in the order of ids; firmware maps an id to the Firmware
        Version it reports (default: its model's), or lists one per servo (None: its model's),
        which must be one that has that model's table. ValueError for a bad id or firmware.
        """
        self.lock = threading.RLock()
        self._clock = clock
        self._random = random.Random(seed)
        self._parser = StreamParser()
        self._parser1 = StreamParser1()
        # How far behind a servo's physics may be when a packet arrives. 0: brought up to date
        # at every packet. A server with idle time (virtual_bus --timing wire) raises it and
        # calls advance_stalest() between packets, so replies are not held up by the physics.
        self.physics_lag_s = 0.0
        self.last_packet_s = float('-inf')
        now_s = clock()
        ids = [int(servo_id) for servo_id in ids]
        slot_models: list[Model] = _per_servo('models', ids, models, MANUAL_MODEL)
        slot_firmware: list[int | None] = _per_servo('firmware', ids, firmware, None)
        self._slots: list[_Slot] = []
        for servo_id, model, version in zip(ids, slot_models, slot_firmware):
            if not 0 <= servo_id <= MAX_ID:
                raise ValueError(f'servo id {servo_id} outside 0..{MAX_ID}')
            servo = SimServo(servo_id, ServoDynamics(model=model), now_s,
                             boot_time_s=boot_time_s, model=model, firmware_version=version)
            self._slots.append(_Slot(servo))

    # ---- the wire -----------------------------------------------------------------------------
    def feed(self, data: bytes, baud_bps: int) -> list[Reply]:
        """Take bytes that arrived at baud_bps; return the status packets in wire order."""
        with self.lock:
            now_s = self._clock()
            events = self._parser.feed(bytes(data), now_s)
            events1 = self._parser1.feed(bytes(data), now_s)
            if not events and not events1:
                return []
            self.last_packet_s = now_s
            lag_s = self.physics_lag_s
            for slot in self._slots:
                slot.servo.advance(now_s, lag_s)
            replies: list[Reply] = []
            for event in events:
                order = _reply_order(event.packet) if event.crc_ok else None
                # Sent to one id, 0x8A or 0x9A gets that servo's ordinary Instruction-error
                # status.
                fast = (order is not None
                        and event.packet.instruction in _FAST_READS
                        and event.packet.servo_id == BROADCAST_ID)
                answered: list[tuple[int, int, Reply]] = []
                for index, slot in self._hearing(baud_bps):
                    servo_id = slot.servo.servo_id
                    status = slot.servo.handle(event, now_s)
                    if status is None:
                        continue
                    reply = (self._inject_part(slot, status, servo_id) if fast
                             else self._inject(slot, status, servo_id))
                    if reply is None:
                        continue
                    rank = order.get(servo_id, _LAST) if order is not None else servo_id
                    answered.append((rank, index, reply))
                if fast and order is not None:
                    if answered:   # (a malformed request, answered by none, has no lengths)
                        replies.extend(_fast_reply(_ranks(answered),
                                                   _fast_lengths(event.packet, len(order))))
                else:
                    replies.extend(_on_the_wire(answered, baud_bps))
            for event in events1:
                replies.extend(self._answer1(event, baud_bps, now_s))
            return replies

    def _hearing(self, baud_bps: int) -> Iterator[tuple[int, _Slot]]:
        """Yield (place in --ids, slot) of the servos on the bus at this baud: who hears it."""
        for index, slot in enumerate(self._slots):
            if slot.plugged and slot.servo.baud_bps == baud_bps:
                yield index, slot

    def _answer1(self, event: ParseEvent, baud_bps: int, now_s: float) -> list[Reply]:
        """Return the Protocol 1.0 servos' replies to one 1.0 packet, in wire order."""
        order = protocol1.reply_order(event.packet) if event.crc_ok else None
        answered: list[tuple[int, int, Reply]] = []
        for index, slot in self._hearing(baud_bps):
            servo_id = slot.servo.servo_id
            status = protocol1.handle(slot.servo, event, now_s)
            if status is None:
                continue
            # Past the header, id and length: the checksum fails, the packet is still framed.
            reply = self._inject(slot, status, servo_id, 4)
            if reply is None:
                continue
            rank = order.get(servo_id, _LAST) if order is not None else servo_id
            answered.append((rank, index, reply))
        return _on_the_wire(answered, baud_bps)

    def advance_stalest(self, min_age_s: float) -> bool:
        """
        Bring the servo whose physics is the oldest up to now, if it is min_age_s behind.

        Returns whether one was advanced: a server calls this in its idle time, one servo at a
        time, checking for incoming bytes in between.
        """
        with self.lock:
            now_s = self._clock()
            stalest = min(self._slots, key=lambda slot: slot.servo.physics_time_s, default=None)
            if stalest is None or now_s - stalest.servo.physics_time_s < min_age_s:
                return False
            stalest.servo.advance(now_s)
            return True

    def _inject(self, slot: _Slot, status: bytes, servo_id: int,
                after: int = 7) -> Reply | None:
        rng = self._random
        if slot.drop_probability and rng.random() < slot.drop_probability:
            return None
        if slot.corrupt_probability and rng.random() < slot.corrupt_probability:
            corrupted = bytearray(status)
            # Past the header, id and length, so the receiver frames it and its CRC fails.
            position = rng.randrange(after, len(corrupted))
            corrupted[position] ^= 1 << rng.randrange(8)
            status = bytes(corrupted)
        return Reply(status, servo_id, slot.servo.return_delay_s)

    def _inject_part(self, slot: _Slot, part: bytes, servo_id: int) -> Reply | None:
        """Fault injection for one servo's part of a fast read (framed afterwards)."""
        rng = self._random
        if slot.drop_probability and rng.random() < slot.drop_probability:
            return None
        flip = -1
        if slot.corrupt_probability and rng.random() < slot.corrupt_probability:
            flip = rng.randrange(len(part) * 8)
        # The flip is applied once the packet is framed: on the wire, after every CRC.
        return Reply(part, servo_id, slot.servo.return_delay_s, flip)

    # ---- inspection ---------------------------------------------------------------------------
    def servo_ids(self) -> list[int]:
        """Return the current ids of all servos on the bus (plugged or not), ascending."""
        with self.lock:
            return sorted(slot.servo.servo_id for slot in self._slots)

    def servos(self) -> list[SimServo]:
        """Return every servo (plugged or not) in the order given to the bus: '#1' first."""
        with self.lock:
            return [slot.servo for slot in self._slots]

    def plugged(self, servo_id: ServoRef) -> bool:
        """Return whether the servo is on the bus."""
        with self.lock:
            return self._slot(servo_id).plugged

    def read_register(self, servo_id: ServoRef, name: str) -> int:
        """Return one register of a servo, brought up to the clock's time."""
        with self.lock:
            servo = self._servo(servo_id)
            if not servo.memory.has(name):
                raise ValueError(f'servo {servo_id} ({servo.model.label}) has no control-table '
                                 f'item named {name!r}')
            servo.advance(self._clock())
            return servo.memory.get(name)

    def model(self, servo_id: ServoRef) -> Model:
        """Return the model of the servo with this id."""
        with self.lock:
            return self._servo(servo_id).model

    def registers(self, servo_id: ServoRef) -> dict[str, int]:
        """Return every register of a servo by name, brought up to the clock's time."""
        with self.lock:
            servo = self._servo(servo_id)
            servo.advance(self._clock())
            return servo.memory.snapshot()

    def servo(self, servo_id: ServoRef) -> SimServo:
        """Return the SimServo with this id (tests and tools)."""
        with self.lock:
            return self._servo(servo_id)

    # ---- fault injection ----------------------------------------------------------------------
    def reseed(self, seed: int) -> None:
        """Restart the fault-injection random draws from seed (repeatable fault tests)."""
        with self.lock:
            self._random.seed(seed)

    def set_drop(self, servo_id: ServoRef, probability: float) -> None:
        """Lose this servo's status packets with the given probability."""
        with self.lock:
            self._slot(servo_id).drop_probability = _probability(probability)

    def set_corrupt(self, servo_id: ServoRef, probability: float) -> None:
        """Corrupt this servo's status packets with the given probability."""
        with self.lock:
            self._slot(servo_id).corrupt_probability = _probability(probability)

    def set_tick(self, servo_id: ServoRef, tick_ms: int) -> None:
        """Make a servo's Realtime Tick read tick_ms now and count on from there."""
        with self.lock:
            self._servo(servo_id).set_tick(self._clock(), int(tick_ms))

    def inject_error(self, servo_id: ServoRef, kind: str) -> None:
        """
        Latch a hardware error: overload, overheat, voltage, encoder or shock.

        The word names one of the model's Hardware Error Status bits (ERROR_KINDS); the
        bit is the servo's model's.
        """
        name = ERROR_KINDS.get(kind)
        if name is None:
            raise ValueError(f'unknown error kind {kind!r}; one of {", ".join(ERROR_KINDS)}')
        with self.lock:
            servo = self._servo(servo_id)
            servo.advance(self._clock())
            if servo.powered:
                servo.latch_errors(servo.memory.table.error_bits[name])

    def powercycle(self, servo_id: ServoRef) -> None:
        """Cut the power and restore it: RAM defaults, torque off, boot time before it answers."""
        with self.lock:
            slot = self._slot(servo_id)
            now_s = self._clock()
            slot.servo.power_off(now_s)
            if slot.plugged:
                slot.servo.power_on(now_s)

    def unplug(self, servo_id: ServoRef) -> None:
        """Take the servo off the bus (and off the power)."""
        with self.lock:
            slot = self._slot(servo_id)
            slot.servo.power_off(self._clock())
            slot.plugged = False

    def plug(self, servo_id: ServoRef) -> None:
        """Put the servo back on the bus: a power-on."""
        with self.lock:
            slot = self._slot(servo_id)
            if slot.plugged:
                return
            slot.plugged = True
            slot.servo.power_on(self._clock())

    def set_load(self, servo_id: ServoRef, load_nm: float) -> None:
        """Apply a resisting torque at the horn."""
        load_nm = float(load_nm)
        if not load_nm >= 0.0 or load_nm == float('inf'):
            raise ValueError(f'load must be a finite torque >= 0 N.m, got {load_nm}')
        with self.lock:
            servo = self._servo(servo_id)
            servo.advance(self._clock())
            servo.dynamics.set_load(load_nm)

    def set_voltage(self, servo_id: ServoRef, volts: float) -> None:
        """Set the servo's supply voltage."""
        volts = float(volts)
        if not 0.0 <= volts <= 30.0:
            raise ValueError(f'voltage must be within 0..30 V, got {volts}')
        with self.lock:
            servo = self._servo(servo_id)
            servo.advance(self._clock())
            servo.dynamics.set_input_voltage(volts)

    def turn(self, servo_id: ServoRef, rad: float, seconds: float = TURN_SECONDS) -> None:
        """
        Turn the horn by hand to rad (servo radians) at constant speed over seconds (0: at once).

        It stops at an end stop on the way; ValueError while torque is on (the motor holds it).
        The horn stays where it is left.
        """
        with self.lock:
            self._servo(servo_id).turn(self._clock(), float(rad), float(seconds))

    def set_stops(self, servo_id: ServoRef, stops: tuple[float, float] | None) -> None:
        """
        Put mechanical end stops at (MIN, MAX) servo radians, or take them away (None).

        Nothing moves the horn past them. ValueError if the horn is not between them now.
        """
        with self.lock:
            self._servo(servo_id).set_stops(self._clock(), stops)

    # ---- helpers ------------------------------------------------------------------------------
    def _slot(self, servo_id: ServoRef) -> _Slot:
        """Return the slot a ServoRef names; ValueError naming the slots of an ambiguous id."""
        if isinstance(servo_id, str):
            number = _slot_number(servo_id)
            if not 1 <= number <= len(self._slots):
                count = len(self._slots)
                raise ValueError(f'no servo {servo_id} on the bus (it has #1..#{count})')
            return self._slots[number - 1]
        found = [number for number, slot in enumerate(self._slots, 1)
                 if slot.servo.servo_id == servo_id]
        if len(found) == 1:
            return self._slots[found[0] - 1]
        if found:
            names = ', '.join(f'#{number}' for number in found)
            raise ValueError(f'id {servo_id} is ambiguous: servos {names} have it; name one as #N')
        known = sorted(slot.servo.servo_id for slot in self._slots)
        raise ValueError(f'no servo with id {servo_id!r} on the bus (ids: {known})')

    def _servo(self, servo_id: ServoRef) -> SimServo:
        return self._slot(servo_id).servo


def _slot_number(ref: str) -> int:
    """Return N of a '#N' reference; ValueError if it is not one."""
    digits = ref[1:]
    if not ref.startswith('#') or not digits.isdigit():
        raise ValueError(f"bad servo reference {ref!r}: expected an id or '#N'")
    return int(digits)


def _per_servo(what: str, ids: list[int], given: Mapping[int, Any] | Sequence[Any] | None,
               default: Any) -> list[Any]:
    """Return one value per servo from a mapping by id or a list in the order of ids."""
    if given is None:
        return [default] * len(ids)
    if isinstance(given, Mapping):
        strays = sorted(set(given) - set(ids))
        if strays:
            raise ValueError(f'{what} names ids {strays}, which are not on the bus {ids}')
        return [given.get(servo_id, default) for servo_id in ids]
    values = list(given)
    if len(values) != len(ids):
        raise ValueError(f'{what}: {len(values)} given for {len(ids)} servos')
    return [default if value is None else value for value in values]


def _ranks(answered: list[tuple[int, int, Reply]]) -> list[list[tuple[int, Reply]]]:
    """Return the replies grouped by wire rank, in wire order: (servo index, reply) each."""
    answered.sort(key=lambda entry: (entry[0], entry[1]))
    groups: list[list[tuple[int, Reply]]] = []
    last_rank = -1
    for rank, index, reply in answered:
        if not groups or rank != last_rank:
            groups.append([])
            last_rank = rank
        groups[-1].append((index, reply))
    return groups


def _on_the_wire(answered: list[tuple[int, int, Reply]], baud_bps: int) -> list[Reply]:
    """Return the replies in wire order, those answering at one rank collided into one."""
    return [group[0][1] if len(group) == 1 else _collide(group, baud_bps)
            for group in _ranks(answered)]


def _collide(group: list[tuple[int, Reply]], baud_bps: int) -> Reply:
    """
    Return what the line carries when these servos answer at once (sim/collision.py).

    Each starts its Return Delay Time after the request, plus its skew: SKEW_BITS bit times
    per place in the bus's order, so that no two start in the same bit.
    """
    streams = [(round(reply.return_delay_s * baud_bps) + SKEW_BITS * index, reply.data)
               for index, reply in group]
    first_bit = min(start for start, _ in streams)
    return Reply(wired_and(streams), group[0][1].servo_id, first_bit / baud_bps)


def _probability(probability: float) -> float:
    probability = float(probability)
    if not 0.0 <= probability <= 1.0:
        raise ValueError(f'probability must be within 0..1, got {probability}')
    return probability


def _fast_reply(ranks: list[list[tuple[int, Reply]]], lengths: tuple[int, ...]) -> list[Reply]:
    """
    Frame the parts of a fast read into the one status packet the servos put on the wire.

    ranks holds the parts at each place of the packet (several: servos sharing an id, whose
    parts collide there; the first one's is framed, the others' are sent over it, each its
    skew later). lengths are those of every servo asked (the length field counts them all).
    The manual does not say what real servos do when one of those asked is silent; here its
    part is left out and the rest follow, so the packet is shorter than its length field. The
    first servo that answers sets the return delay.
    """
    if not ranks:
        return []
    parts = [group[0][1] for group in ranks]
    packet = bytearray(encode_fast_status(
        [(part.data[0], part.data[1], part.data[2:]) for part in parts], lengths))
    offset = FAST_HEAD_SIZE
    overlays: list[tuple[int, bytes]] = []
    for group in ranks:
        index, part = group[0]
        if part.flip_bit >= 0:
            packet[offset + part.flip_bit // 8] ^= 1 << (part.flip_bit % 8)
        for other_index, other in group[1:]:
            overlays.append((offset * BITS_PER_FRAME + SKEW_BITS * (other_index - index),
                             other.data))
        offset += len(part.data) + 2
    data = wired_and([(0, bytes(packet)), *overlays]) if overlays else bytes(packet)
    return [Reply(data, BROADCAST_ID, parts[0].return_delay_s)]


def _fast_lengths(packet: Packet, count: int) -> tuple[int, ...]:
    """Return the data lengths of the count servos a well-formed fast read asks, in order."""
    params = packet.params
    if packet.instruction == Instruction.FAST_SYNC_READ:
        return (params[2] | params[3] << 8,) * count
    # A Fast Bulk Read: each id's first record (the one its servo answers).
    lengths: dict[int, int] = {}
    for start in range(0, len(params) - 4, 5):
        lengths.setdefault(params[start], params[start + 3] | params[start + 4] << 8)
    return tuple(lengths.values())


def _reply_order(packet: Packet) -> dict[int, int] | None:
    """Return id -> wire rank for packets answered by several servos, None for id order."""
    params = packet.params
    if packet.instruction in (Instruction.SYNC_READ, Instruction.FAST_SYNC_READ):
        ids = params[4:]
    elif (packet.instruction in (Instruction.BULK_READ, Instruction.FAST_BULK_READ)
          and packet.servo_id == BROADCAST_ID):
        ids = params[0::5] if len(params) % 5 == 0 else b''
    else:
        return None
    order: dict[int, int] = {}
    for rank, servo_id in enumerate(ids):
        order.setdefault(servo_id, rank)
    return order
