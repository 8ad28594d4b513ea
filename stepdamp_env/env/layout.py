"""Named layouts of the observation and the action, for baselines and agents.

Read entries by name, never by a bare position::

    from stepdamp_env.env.layout import OBS, HARMONIC_SIN, HARMONIC_COS
    velocity_error = observation[OBS.velocity_error]
    sines = observation[HARMONIC_SIN]          # sin x, sin 2x, sin 4x

The positions are those the compiled step writes (:mod:`.compiled`).
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from ..params import DETENT_HARMONICS
from . import compiled as C

__all__ = ["ObservationIndex", "OBS", "OBSERVATION_NAMES", "OBSERVATION_UNITS",
           "PRIVILEGED_NAMES", "HARMONIC_SIN", "HARMONIC_COS", "ACTION_MODES",
           "ACTION_NAMES", "observation_names", "OBS_BOUND"]

OBS_BOUND = C.OBS_BOUND

#: Positions of the base observation entries (the same in every action mode),
#: named in lower case: ``OBS.velocity_error``.
ObservationIndex = namedtuple("ObservationIndex", [f.lower() for f in C.OBS._fields])
OBS = ObservationIndex(*C.OBS)
OBSERVATION_NAMES: tuple[str, ...] = ObservationIndex._fields
# Meaning and unit of each base entry (the env's docstring table).
OBSERVATION_UNITS: dict[str, str] = {
    "position_error": "(theta_cmd - encoder angle) / full step",
    "velocity_error": "(omega_cmd - filtered encoder velocity) / held command speed",
    "sin_x": "sin of the electrical (Park) angle x", "cos_x": "cos x",
    "sin_2x": "sin 2x", "cos_2x": "cos 2x", "sin_4x": "sin 4x", "cos_4x": "cos 4x",
    "speed_command": "omega_cmd / (2*pi*max(speed_range_rps[1], speed_rps))",
    "id": "measured id / holding current", "iq": "measured iq / holding current",
}
PRIVILEGED_NAMES = tuple("true_" + f.lower() for f in C.PRIVILEGED._fields)

# sin and cos entries of the detent harmonics h = 1, 2, 4 (in DETENT_HARMONICS order).
HARMONIC_SIN = np.array([OBS.sin_x, OBS.sin_2x, OBS.sin_4x])
HARMONIC_COS = np.array([OBS.cos_x, OBS.cos_2x, OBS.cos_4x])
assert DETENT_HARMONICS == (1, 2, 4)

# Action entries per action mode: ds<h>, dc<h> are corrections (N*m) of the
# feedforward's sin/cos coefficient of harmonic h; iq a q current (A).
_HARMONIC_ACTIONS = tuple(f"{kind}{h}" for h in DETENT_HARMONICS for kind in ("ds", "dc"))
ACTION_NAMES: dict[str, tuple[str, ...]] = {
    "harmonic": _HARMONIC_ACTIONS,
    "current": ("iq",),
    "harmonic+current": _HARMONIC_ACTIONS + ("iq",),
}
ACTION_MODES = tuple(ACTION_NAMES)


def observation_names(action_mode: str = "harmonic", privileged: bool = False
                      ) -> tuple[str, ...]:
    """Names of every observation entry in order for an env with these options."""
    last = tuple(f"last_action_{n}" for n in ACTION_NAMES[action_mode])
    return OBSERVATION_NAMES + last + (PRIVILEGED_NAMES if privileged else ())
