"""The torch on the Z carriage: floating head, float switch, breakaway and ohmic contact.

The tip sits at the carriage Z while it is above the plate. Once the carriage goes below
the surface the tip rests on the plate and the head slides up on its float:
``compression = surface_z - carriage_z``. The float switch closes at ``float_travel_mm`` of
compression, opens below ``float_travel_mm - float_hysteresis_mm``, and bounces for
``float_bounce_ms`` after each change. Compression beyond ``max_float_mm`` trips the
breakaway switch, which stays latched until ``reset_breakaway`` with the head back in range.
"""

import random

from .scenario import SurfaceSpec, TorchSpec

__all__ = ["TorchHead"]

_CLEAN, _RUSTY, _PAINTED, _WET = 0, 1, 2, 3
_CONDITION_CODES = {"clean": _CLEAN, "rusty": _RUSTY, "painted": _PAINTED, "wet": _WET}


class TorchHead:
    """Floating torch head sensors; call ``update`` once per sample period."""

    __slots__ = (
        "_bounce_s",
        "_close_mm",
        "_condition",
        "_float_state",
        "_float_switch_t",
        "_max_float_mm",
        "_open_mm",
        "_rng",
        "_rusty_p",
        "_t_s",
        "_wet_film_mm",
        "_wet_p",
        "breakaway",
        "compression_mm",
        "float_switch",
        "ohmic_contact",
        "touching",
        "true_height_mm",
    )

    def __init__(self, torch: TorchSpec, surface: SurfaceSpec, rng: random.Random) -> None:
        self._rng = rng
        self._close_mm = torch.float_travel_mm
        self._open_mm = torch.float_travel_mm - torch.float_hysteresis_mm
        self._bounce_s = torch.float_bounce_ms / 1000.0
        self._max_float_mm = torch.max_float_mm
        self._condition = _CONDITION_CODES[surface.condition]
        self._rusty_p = surface.rusty_contact_probability
        self._wet_film_mm = surface.wet_film_mm
        self._wet_p = surface.wet_contact_probability
        self._t_s = 0.0
        self._float_state = False
        self._float_switch_t = -1.0
        self.true_height_mm = 0.0
        self.compression_mm = 0.0
        self.touching = False
        self.float_switch = False
        self.breakaway = False
        self.ohmic_contact = False

    def reset_breakaway(self) -> bool:
        """Clear the breakaway latch if the head is back in range; return the new state."""
        if self.compression_mm < self._max_float_mm:
            self.breakaway = False
        return self.breakaway

    def trip_breakaway(self) -> None:
        """Latch the breakaway switch (fault injection: a tip-up or a collision)."""
        self.breakaway = True

    def update(
        self, carriage_z_mm: float, surface_z_mm: float, ohmic_enabled: bool, dt_s: float
    ) -> None:
        """Recompute the head's sensors for the carriage and plate heights of this sample."""
        t = self._t_s + dt_s
        self._t_s = t
        gap = carriage_z_mm - surface_z_mm
        if gap > 0.0:
            self.true_height_mm = gap
            compression = 0.0
            self.touching = False
        else:
            self.true_height_mm = 0.0
            compression = -gap
            self.touching = True
        self.compression_mm = compression

        state = self._float_state
        if (not state and compression >= self._close_mm) or (state and compression < self._open_mm):
            state = not state
            self._float_state = state
            self._float_switch_t = t
            self.float_switch = state
        elif t - self._float_switch_t < self._bounce_s:
            self.float_switch = self._rng.random() < 0.5
        else:
            self.float_switch = state

        if compression >= self._max_float_mm:
            self.breakaway = True

        if not ohmic_enabled:
            self.ohmic_contact = False
            return
        condition = self._condition
        if condition == _CLEAN:
            self.ohmic_contact = self.touching
        elif condition == _RUSTY:
            self.ohmic_contact = self.touching and self._rng.random() < self._rusty_p
        elif condition == _WET:
            if self.touching:
                self.ohmic_contact = True
            else:
                in_film = gap <= self._wet_film_mm
                self.ohmic_contact = in_film and self._rng.random() < self._wet_p
        else:
            self.ohmic_contact = False
