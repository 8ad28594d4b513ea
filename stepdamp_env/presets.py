"""Named preset systems: the patent's drive and real Trinamic motors.

Each preset gives its provenance beside its numbers: the document a value is
taken from, or ASSUMED where the document is silent. :func:`get_preset` and
:func:`preset_names` are also importable from :mod:`stepdamp_env`, as is
:data:`PRESETS`.
"""

from __future__ import annotations

import math
from typing import Callable

from .params import DriveParams, MotorParams, ParameterError, ServoParams, SystemParams

__all__ = ["PRESETS", "preset_names", "get_preset"]


def _patent() -> SystemParams:
    """The system of US 7,733,051.

    Where the patent is silent the values are ASSUMED, those of a 57 mm
    (NEMA 23) hybrid stepper of the patent's torque constant. J puts the three
    predicted resonances (``predicted_resonances_rps``) at 0.672, 1.343 and
    2.687 rev/s (h = 4, 2, 1; tests/test_bench_v3.py); the 1st and 2nd detent
    harmonics stand for the manufacturing imperfections that give a real motor
    its 2nd and 1st harmonic resonances.
    """
    motor = MotorParams(
        R=1.2,          # Ohm, ASSUMED
        L=3.6e-3,       # H, ASSUMED
        Km=0.3,         # N*m/A, patent section A
        Nr=50,          # rotor teeth, patent section A
        J=4.0e-5,       # kg*m^2, ASSUMED: rotor about 1.2e-5 + rigid load 2.8e-5
        D=0.001,        # N*m*s/rad, patent eq. 9
        Kd1=0.004,      # N*m, ASSUMED
        Kd2=0.006,      # N*m, ASSUMED
        Kd4=0.012,      # N*m, ASSUMED: 2 % of the 0.57 N*m holding torque at 1.9 A
        phi1=-1.1,      # rad, ASSUMED
        phi2=0.6,       # rad, ASSUMED
        Fs=0.004,       # N*m, ASSUMED
        load_torque=0.0,  # N*m, none
    )
    drive = DriveParams(
        Vdc=48.0,                    # V, ASSUMED
        pwm_hz=20_000.0,             # Hz, patent: PWM and control rate
        holding_current=1.9,         # A, patent eq. 7
        microsteps=64,               # patent description: 1/64 microstepping
        current_bandwidth_hz=1_500.0,  # Hz, ASSUMED (module default)
    )
    servo = ServoParams(encoder_cpr=4000)   # counts/rev, patent section C
    return SystemParams(motor, drive, servo, name="patent")


# Real motors. Conventions of every datasheet preset (see _datasheet_motor):
# * holding torque is taken with both phases at the rated RMS current, so the
#   sinusoidal-microstep amplitude is sqrt(2)*I_rated (that is holding_current)
#   and Km = T_hold / (sqrt(2)*I_rated), giving Km*holding_current = T_hold;
# * the datasheet detent torque is the peak of the detent curve, split ASSUMED
#   60 % / 25 % / 15 % over the 4th / 2nd / 1st harmonic, phases ASSUMED;
# * J = rotor inertia plus an ASSUMED rigidly coupled load of nine times the
#   rotor's (10:1 total to rotor, the usual upper end for open-loop steppers;
#   lighter loads push the resonances to speeds where the drive's own
#   electrical dynamics shift the peaks further from the rigid-spring formula);
# * D ASSUMED so that the mechanical damping ratio D/(2*sqrt(Km*I*Nr*J)) is
#   0.02, a lightly damped rig like the patent's; Fs ASSUMED about 1 % of T_hold;
# * Nr = 50 from the datasheets' 1.8 degree step; the drive (20 kHz PWM, 1/64
#   microsteps, 1.5 kHz current loops, 4000 count/rev encoder) ASSUMED to be
#   the patent's.
# The detent also modulates the spring by +-4*Nr*Kd4; past a modulation depth
# eps = 4*Kd4/T_hold of about 4*zeta (the total damping ratio: mechanical D
# plus the drive's electrical damping) that drives a parametric (Mathieu)
# resonance at the h=2 speed which no feedforward at the command angle removes
# (README, "Known limits"): the QSH4218-35-10-027 (eps = 0.2) is left out for that.
_SQRT2 = math.sqrt(2.0)


def _datasheet_motor(*, name: str, i_rated: float, r: float, l: float, t_hold: float,
                     detent: float, j_rotor: float, vdc: float,
                     fs: float, phi1: float, phi2: float) -> SystemParams:
    """A system from datasheet values (SI units) and the conventions above."""
    j = 10.0 * j_rotor
    stiffness = t_hold * 50          # Km*holding_current*Nr, N*m/rad
    d = 2.0 * 0.02 * math.sqrt(stiffness * j)
    motor = MotorParams(R=r, L=l, Km=t_hold / (_SQRT2 * i_rated), Nr=50, J=j, D=d,
                        Kd1=0.15 * detent, Kd2=0.25 * detent, Kd4=0.6 * detent,
                        phi1=phi1, phi2=phi2, Fs=fs, load_torque=0.0)
    drive = DriveParams(Vdc=vdc, pwm_hz=20_000.0, holding_current=_SQRT2 * i_rated,
                        microsteps=64, current_bandwidth_hz=1_500.0)
    return SystemParams(motor, drive, ServoParams(encoder_cpr=4000), name=name)


def _qsh4218_51_10_049() -> SystemParams:
    """Trinamic QSH4218-51-10-049, NEMA 17, 1.8 degree.

    Source: Trinamic "QMot QSH4218 manual" V1.10, table 2.1, unless ASSUMED.
    """
    return _datasheet_motor(
        name="qsh4218-51-10-049",
        i_rated=1.0,        # A RMS, rated current (table 2.1)
        r=5.0,              # Ohm (table 2.1)
        l=8.0e-3,           # H, 8.0 mH (table 2.1)
        t_hold=0.49,        # N*m, holding torque (table 2.1)
        detent=0.028,       # N*m, detent torque 28 mN*m (table 2.1)
        j_rotor=68e-7,      # kg*m^2, rotor inertia 68 g*cm^2 (table 2.1)
        vdc=24.0,           # V, supply of the manual's torque curve
        fs=0.005,           # N*m, ASSUMED about 1 % of t_hold
        phi1=0.9,           # rad, ASSUMED
        phi2=-0.5,          # rad, ASSUMED
    )


def _qsh5718_56_28_126() -> SystemParams:
    """Trinamic QSH5718-56-28-126, NEMA 23, 1.8 degree.

    Source: Trinamic "QMot QSH5718 manual" V2.6, table 2.1, unless ASSUMED.
    """
    return _datasheet_motor(
        name="qsh5718-56-28-126",
        i_rated=2.8,        # A RMS, rated current (table 2.1)
        r=0.9,              # Ohm (table 2.1)
        l=2.5e-3,           # H, 2.5 mH (table 2.1)
        t_hold=1.26,        # N*m, holding torque (table 2.1)
        detent=0.039,       # N*m, detent torque (table 2.1)
        j_rotor=300e-7,     # kg*m^2, rotor inertia 300 g*cm^2 (table 2.1)
        vdc=30.0,           # V, supply of the manual's torque curve
        fs=0.012,           # N*m, ASSUMED about 1 % of t_hold
        phi1=0.3,           # rad, ASSUMED
        phi2=2.0,           # rad, ASSUMED
    )


def _qsh6018_65_28_210() -> SystemParams:
    """Trinamic QSH6018-65-28-210, 60 mm flange, 1.8 degree.

    Source: Trinamic "QMot QSH6018 manual" V1.20, table 1.1, unless ASSUMED.
    """
    return _datasheet_motor(
        name="qsh6018-65-28-210",
        i_rated=2.8,        # A RMS, rated current (table 1.1)
        r=1.2,              # Ohm (table 1.1)
        l=4.6e-3,           # H, 4.6 mH (table 1.1)
        t_hold=2.1,         # N*m, holding torque (table 1.1)
        detent=0.06,        # N*m, ASSUMED: the table leaves it blank; about 3 %
                            # of t_hold, in line with the family's smaller motors
        j_rotor=570e-7,     # kg*m^2, rotor inertia 570 g*cm^2 (table 1.1)
        vdc=30.0,           # V, supply of the manual's torque curves
        fs=0.02,            # N*m, ASSUMED about 1 % of t_hold
        phi1=-1.3,          # rad, ASSUMED
        phi2=0.4,           # rad, ASSUMED
    )


PRESETS: dict[str, Callable[[], SystemParams]] = {
    "patent": _patent,
    "qsh4218-51-10-049": _qsh4218_51_10_049,
    "qsh5718-56-28-126": _qsh5718_56_28_126,
    "qsh6018-65-28-210": _qsh6018_65_28_210,
}


def preset_names() -> list[str]:
    """Names accepted by :func:`get_preset` and by ``--motor``."""
    return sorted(PRESETS)


def get_preset(name: str) -> SystemParams:
    """A preset system by name; ``ParameterError`` lists the names on a miss."""
    try:
        factory = PRESETS[name]
    except KeyError:
        raise ParameterError(
            f"unknown motor preset {name!r}; choose one of {preset_names()} "
            "or give a path to a motor .json file") from None
    return factory()
