"""What the Dynamixel backend makes of a read that failed all its tries: a servo that stopped
answering (ServoTimeoutError, named by pinging each), a bus that stalled as a whole or outlived
the servos' Bus Watchdog (BusStallError), a corrupt line. Mixed into backend.DynamixelBus (the
rules: hal/dynamixel/backend.py's docstring)."""

from __future__ import annotations

import time

from ..errors import BusStallError, ServoOperationError, ServoTimeoutError
from .control_table import ADDR_BUS_WATCHDOG
from .fast_read import NO_REPLY


class Diagnosis:
    """The stall diagnosis of backend.DynamixelBus."""

    def _diagnose(self, detail: str, suspect=None) -> ServoTimeoutError | BusStallError:
        """After the retries, ping every servo (with as many tries) to find those that stopped
        answering. None answers: the bus stalled. Some did not: once the others have answered
        (the bus is alive), ping those again and name the first still silent. If every servo
        answers, name the one whose block the short reply lacked — or, when no byte of the reply
        came at all, the whole bus had stalled and came back."""
        silent = [joint for joint in self.joints if not self._answers_ping(joint)]
        pings = f"{self.retries + 1} pings"
        if len(silent) == len(self.joints):
            return BusStallError(self.bus.name, f"{detail}; no answer to {pings} of each servo")
        still = [joint for joint in silent if not self._answers_ping(joint)]
        if still:
            joint = still[0]
            return ServoTimeoutError(joint.dof, joint.id, f"{detail}; no answer to {pings}, twice, while the "
                                                          "others answered")
        if detail == NO_REPLY:
            return BusStallError(self.bus.name, f"{detail} to {self.retries + 1} tries, then every servo answered "
                                                "a ping")
        joint = suspect or (silent or self.joints)[0]
        return ServoTimeoutError(joint.dof, joint.id, f"{detail} (every servo answers a ping)")

    def _corrupt_line(self, detail: str) -> ServoOperationError | None:
        """After the retries, one ping of each servo: a servo whose answer comes but is corrupt
        (bad CRC, garbage, cut) is on a corrupt line, not silent. None when no answer is corrupt."""
        for joint in self.joints:
            if self.packets.ping(self.port, joint.id)[1] == self._sdk.COMM_RX_CORRUPT:
                return ServoOperationError(f"bus '{self.bus.name}': corrupt replies ({detail}; joint "
                                           f"'{joint.dof}' (id {joint.id}) answers a ping with a corrupt packet)")
        return None

    def _answers_ping(self, joint) -> bool:
        return any(self.packets.ping(self.port, joint.id)[1] == self._sdk.COMM_SUCCESS
                   for _ in range(self.retries + 1))

    def _check_watchdog(self, silence: float) -> None:
        """After `silence` s without a packet: raise BusStallError if a servo tripped its Bus
        Watchdog (it reads -1, 255 unsigned)."""
        tripped = [joint.id for joint in self.joints if self._read_item(joint, ADDR_BUS_WATCHDOG, 1) == 0xFF]
        if tripped:
            raise BusStallError(self.bus.name, f"{silence * 1e3:.0f} ms without a packet, over the servos' Bus "
                                f"Watchdog of {self.watchdog * 1e3:.0f} ms: servos {', '.join(map(str, tripped))} "
                                "tripped it and stopped")
        self._heard = time.monotonic()          # every servo answered

    def _check_silence(self, now: float) -> None:
        """With torque on, raise BusStallError once the bus has said nothing for longer than the
        servos' Bus Watchdog: on real servos it has tripped (torque off, goals refused), whether
        or not they can be asked now, so the run cannot go on; and a reply that ends such a
        silence may be the answer to an earlier try, held back with the bus, not the retry's. A
        short hiccup (a lost packet retried within the watchdog) goes on as a retry."""
        if not self._armed or self._heard is None or now - self._heard <= self.watchdog:
            return
        raise BusStallError(self.bus.name, f"silent for {(now - self._heard) * 1e3:.0f} ms, longer than the "
                                           f"servos' Bus Watchdog of {self.watchdog * 1e3:.0f} ms: they have "
                                           "switched their torque off by themselves")
