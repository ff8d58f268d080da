"""Fault injection on the rig's outgoing frames (``nfal rig-emulator --drop --corrupt --duplicate --delay``).

:class:`FaultInjector` sits between the emulated rig and its port: each frame for the host is dropped,
corrupted (one bit of one byte flipped, the delimiter spared), duplicated, and/or held back by a fixed
delay, with seeded randomness. Disconnection is the port's business (:mod:`nfal.hil.ports`).
"""

from __future__ import annotations

import collections
import dataclasses
import random

from nfal.errors import InvalidParameterError


@dataclasses.dataclass(frozen=True)
class FaultSettings:
    """Rates are probabilities per frame in [0, 1]; ``delay_s`` is added to every frame [s]."""

    drop: float = 0.0
    corrupt: float = 0.0
    duplicate: float = 0.0
    delay_s: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("drop", "corrupt", "duplicate"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise InvalidParameterError(name, value, "a rate in [0, 1]")
        if not 0.0 <= self.delay_s <= 10.0:
            raise InvalidParameterError("delay_s", self.delay_s, "in [0, 10] s")
        if not isinstance(self.seed, int) or self.seed < 0:  # random.Random(-n) is random.Random(n): not a new seed
            raise InvalidParameterError("seed", self.seed, "a whole number >= 0")

    @property
    def active(self) -> bool:
        return bool(self.drop or self.corrupt or self.duplicate or self.delay_s)


@dataclasses.dataclass
class FaultCounts:
    dropped: int = 0
    corrupted: int = 0
    duplicated: int = 0


class FaultInjector:
    """Frames in (with the current wall time), frames due out (see the module docstring)."""

    def __init__(self, settings: FaultSettings = FaultSettings()) -> None:
        self.settings = settings
        self.counts = FaultCounts()
        self._random = random.Random(settings.seed)
        self._held: collections.deque[tuple[float, bytes]] = collections.deque()

    def _mangle(self, frame: bytes) -> list[bytes]:
        s, rng = self.settings, self._random
        if s.drop and rng.random() < s.drop:
            self.counts.dropped += 1
            return []
        if s.corrupt and rng.random() < s.corrupt:
            damaged = bytearray(frame)
            position = rng.randrange(len(damaged) - 1)  # never the delimiter
            damaged[position] ^= 1 << rng.randrange(8)
            frame = bytes(damaged)
            self.counts.corrupted += 1
        if s.duplicate and rng.random() < s.duplicate:
            self.counts.duplicated += 1
            return [frame, frame]
        return [frame]

    def __call__(self, frames: list[bytes], now_s: float) -> list[bytes]:
        """The frames to write now: ``frames`` after the faults, and any held ones that are due."""
        out = [m for frame in frames for m in self._mangle(frame)]
        if not self.settings.delay_s:
            return out
        release = now_s + self.settings.delay_s
        self._held.extend((release, frame) for frame in out)
        due = []
        while self._held and self._held[0][0] <= now_s:
            due.append(self._held.popleft()[1])
        return due
