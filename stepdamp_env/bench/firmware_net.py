"""A learned entry's policy network for a drive's firmware: :class:`FirmwareNetwork`,
its Python reference :func:`network_actions`, its JSON and its C99.

A learned entry decides every agent step (``decision_hz``): its network maps
the observation the benchmark's env gives it (float32, the names and units in
``observation_names`` and ``observation_units``) to an action in [-1, 1]
(float32, ``action_names``; entry j times ``action_scales[j]`` is the physical
quantity the drive applies until the next decision). The network's every sum
runs in input order in double, as :func:`stepdamp_env.fixednet.mlp_forward`
runs it, and tanh is fdlibm's (:mod:`stepdamp_env.fixedmath`), so the C gives
the simulated policy's action bit for bit on any CPU (compiled without
contraction into fused multiply-adds: ``-ffp-contract=off``; the source sets
it for clang).

What is exported is the network and its action's post-processing (SB3's
clipping, or the unscaling of a squashed output, then [-1, 1]). Computing the
observation on the drive (the errors in the env's units, the history of
earlier errors, the last action, the visible context) and the law that applies
the action (StepperDamp-v1's damping law on ``ff-delay-comp``'s table) are the
firmware's; the header and the JSON say what each input and output is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from ..fixednet import ACTIVATION, mlp_forward
from ..params import ParameterError
from ..version import __version__
from .firmware_c import c_comment, c_double, check_prefix, default_prefix, write_law_files

__all__ = ["FirmwareNetwork", "NETWORK_FORMAT_ID", "ACTIVATIONS", "network_export",
           "network_actions", "network_outputs",
           "network_to_json", "network_from_json", "network_c_source", "export_network"]

#: The JSON file's ``format`` tag.
NETWORK_FORMAT_ID = "stepdamp-firmware-network/1"
#: Activation names, in :data:`stepdamp_env.fixednet.ACTIVATION`'s order.
ACTIVATIONS = tuple(name.lower() for name in ACTIVATION._fields)


def _floats(name: str, values: Any, n: int | None = None) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a sequence of numbers") from None
    if n is not None and len(out) != n:
        raise ParameterError(f"{name} must hold {n} numbers, got {len(out)}")
    if not all(math.isfinite(v) for v in out):
        raise ParameterError(f"{name} must be finite")
    return out


@dataclass(frozen=True)
class FirmwareNetwork:
    """A feed-forward policy network and what its inputs and outputs mean.

    Attributes:
        entry, motor, mode, speed_rps: the entry, and the operating point whose
            ``action_scales`` and ``observation_units`` are given (the network
            itself does not depend on it: the speed is one of its inputs).
        decision_hz: decisions per second (the env's agent rate, Hz).
        observation_names: the network's inputs, in order.
        observation_units: the units the observation divides by (SI), by name.
        action_names: the outputs, in order.
        action_scales: what action entry j means at 1.0 (SI: the units in
            ``notes``), by output.
        sizes: layer widths, inputs first (``sizes[0]`` = len(observation_names),
            ``sizes[-1]`` = len(action_names)).
        activations: per layer, one of :data:`ACTIVATIONS`.
        weights: every layer's (out, in) matrix row by row, one after the other.
        biases: every layer's biases, one after the other.
        squash: SB3's squashed output: the output is unscaled from [-1, 1] to
            [action_low, action_high] (float32) instead of clipped to it.
        action_low, action_high: the model's action space (float32 values).
        notes: what the actions do on the drive.
        constant_inputs: inputs that stay constant over a run, by name, with
            their values at the exported motor and speed (what the drive knows
            of its own model); the firmware feeds them as they are.
    """

    entry: str
    motor: str
    mode: str
    speed_rps: float
    decision_hz: float
    observation_names: tuple[str, ...]
    observation_units: Mapping[str, float]
    action_names: tuple[str, ...]
    action_scales: tuple[float, ...]
    sizes: tuple[int, ...]
    activations: tuple[str, ...]
    weights: tuple[float, ...] = field(repr=False)
    biases: tuple[float, ...] = field(repr=False)
    squash: bool
    action_low: tuple[float, ...]
    action_high: tuple[float, ...]
    notes: str = ""
    constant_inputs: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        sizes = tuple(int(s) for s in self.sizes)
        if len(sizes) < 2 or min(sizes) < 1:
            raise ParameterError(f"sizes={list(self.sizes)} must hold >= 2 widths, each >= 1")
        object.__setattr__(self, "sizes", sizes)
        layers = len(sizes) - 1
        if len(self.activations) != layers or not set(self.activations) <= set(ACTIVATIONS):
            raise ParameterError(f"activations must hold {layers} of {list(ACTIVATIONS)}")
        object.__setattr__(self, "activations", tuple(self.activations))
        n_w = sum(a * b for a, b in zip(sizes, sizes[1:]))
        object.__setattr__(self, "weights", _floats("weights", self.weights, n_w))
        object.__setattr__(self, "biases", _floats("biases", self.biases, sum(sizes[1:])))
        n_in, n_out = sizes[0], sizes[-1]
        if len(self.observation_names) != n_in:
            raise ParameterError(f"observation_names must hold {n_in} names (sizes[0])")
        if len(self.action_names) != n_out:
            raise ParameterError(f"action_names must hold {n_out} names (sizes[-1])")
        object.__setattr__(self, "observation_names", tuple(map(str, self.observation_names)))
        object.__setattr__(self, "action_names", tuple(map(str, self.action_names)))
        object.__setattr__(self, "observation_units", dict(
            zip(self.observation_units, _floats("observation_units",
                                                self.observation_units.values()))))
        object.__setattr__(self, "action_scales", _floats("action_scales", self.action_scales,
                                                          n_out))
        for name in ("action_low", "action_high"):
            values = _floats(name, getattr(self, name), n_out)
            if any(float(np.float32(v)) != v for v in values):
                raise ParameterError(f"{name} must hold float32 values")
            object.__setattr__(self, name, values)
        if any(lo > hi for lo, hi in zip(self.action_low, self.action_high)):
            raise ParameterError("action_low must not exceed action_high")
        if not (math.isfinite(self.decision_hz) and self.decision_hz > 0.0):
            raise ParameterError(f"decision_hz={self.decision_hz!r} must be > 0")
        object.__setattr__(self, "squash", bool(self.squash))
        unknown = set(self.constant_inputs) - set(self.observation_names)
        if unknown:
            raise ParameterError(f"constant_inputs name no input: {sorted(unknown)}")
        object.__setattr__(self, "constant_inputs", dict(
            zip(self.constant_inputs, _floats("constant_inputs",
                                              self.constant_inputs.values()))))

    @property
    def multiply_adds(self) -> int:
        """Multiply-adds per decision (the layers' weights; tanh not counted)."""
        return sum(a * b for a, b in zip(self.sizes, self.sizes[1:]))


def network_export(policy: Any, net: Any, context: Any, *, observation_names: Sequence[str],
                   observation_units: Mapping[str, float], decision_hz: float,
                   action_names: Sequence[str], action_scales: Sequence[float], notes: str,
                   constant_inputs: Mapping[str, float] | None = None) -> FirmwareNetwork:
    """The :class:`FirmwareNetwork` of a learned entry ``policy`` (its ``name`` and
    its SB3 ``model``) whose network ``net`` (a
    :class:`~stepdamp_env.bench.network.PolicyNetwork`) acts at ``context``
    (a :class:`~stepdamp_env.bench.policy.PolicyContext`), with what its inputs
    and outputs mean (the fields of the same names)."""
    model = policy.model
    return FirmwareNetwork(
        entry=policy.name, motor=context.knowledge.nominal.name, mode=context.mode,
        speed_rps=float(context.speed_rps), decision_hz=decision_hz,
        observation_names=tuple(observation_names), observation_units=observation_units,
        action_names=tuple(action_names), action_scales=tuple(action_scales),
        sizes=tuple(int(s) for s in net.sizes),
        activations=tuple(ACTIVATIONS[int(a)] for a in net.activations),
        weights=net.weights, biases=net.biases, squash=bool(model.policy.squash_output),
        action_low=model.action_space.low, action_high=model.action_space.high, notes=notes,
        constant_inputs=dict(constant_inputs or {}))


def network_actions(net: FirmwareNetwork, observations: np.ndarray) -> np.ndarray:
    """The actions (float32, n x k) of observation rows (n x d, read as float32):
    the network in fixed order (:func:`stepdamp_env.fixednet.mlp_forward`), its
    output rounded to float32, then unscaled (``squash``) or clipped to the action
    space in float32, then clipped to [-1, 1]. The reference the C computes."""
    out = network_outputs(net, observations).astype(np.float32)
    low = np.array(net.action_low, dtype=np.float32)
    high = np.array(net.action_high, dtype=np.float32)
    out = low + (0.5 * (out + 1.0) * (high - low)) if net.squash else np.clip(out, low, high)
    return np.clip(out.astype(np.float32), -1.0, 1.0).astype(np.float32)


def network_outputs(net: FirmwareNetwork, observations: np.ndarray) -> np.ndarray:
    """The network's output (float64, n x k) before :func:`network_actions` rounds
    and clips it: :func:`stepdamp_env.fixednet.mlp_forward` of the rows as float32."""
    x = np.ascontiguousarray(np.asarray(observations, dtype=np.float32).reshape(
        -1, net.sizes[0]))
    codes = np.array([ACTIVATIONS.index(a) for a in net.activations], dtype=np.int64)
    return mlp_forward(x, np.array(net.weights), np.array(net.biases),
                       np.array(net.sizes, dtype=np.int64), codes)


def network_to_json(net: FirmwareNetwork) -> dict[str, Any]:
    """The network as a JSON object (``format`` :data:`NETWORK_FORMAT_ID`)."""
    return {"format": NETWORK_FORMAT_ID, "exported_by": f"stepdamp {__version__}",
            "entry": net.entry, "motor": net.motor, "mode": net.mode,
            "speed_rps": net.speed_rps, "decision_hz": net.decision_hz,
            "observation_names": list(net.observation_names),
            "observation_units": dict(net.observation_units),
            "action_names": list(net.action_names), "action_scales": list(net.action_scales),
            "sizes": list(net.sizes), "activations": list(net.activations),
            "squash": net.squash, "action_low": list(net.action_low),
            "action_high": list(net.action_high), "multiply_adds_per_decision": net.multiply_adds,
            "notes": net.notes, "constant_inputs": dict(net.constant_inputs),
            "weights": list(net.weights), "biases": list(net.biases)}


def network_from_json(data: Mapping[str, Any]) -> FirmwareNetwork:
    """The network of :func:`network_to_json`'s object (a one-line error otherwise)."""
    if not isinstance(data, Mapping) or data.get("format") != NETWORK_FORMAT_ID:
        raise ParameterError(f"not a {NETWORK_FORMAT_ID} object")
    fields = ("entry", "motor", "mode", "speed_rps", "decision_hz", "observation_names",
              "observation_units", "action_names", "action_scales", "sizes", "activations",
              "weights", "biases", "squash", "action_low", "action_high", "notes")
    missing = [f for f in fields if f not in data]
    if missing:
        raise ParameterError(f"network JSON lacks {missing}")
    return FirmwareNetwork(**{f: data[f] for f in fields},
                           constant_inputs=data.get("constant_inputs", {}))


def export_network(net: FirmwareNetwork, fmt: str, out_dir: str, prefix: str | None = None
                   ) -> list[str]:
    """Write the network into ``out_dir``, each file atomically: ``<prefix>.json``
    (fmt "json") or ``<prefix>.h`` and ``<prefix>.c`` (fmt "c"). Returns the paths."""
    return write_law_files(fmt, out_dir, default_prefix(net.entry) if prefix is None else prefix,
                           lambda: network_to_json(net), lambda p: network_c_source(net, p))


# fdlibm's exp, expm1 and tanh as stepdamp_env.fixedmath computes them.
_TANH_C = """
static double {p}_exp(double x)
{{
    double k, hi, lo, r, t, c, y;

    if (x != x) {{
        return x;
    }}
    if (x > 7.09782712893383973096e+02) {{
        return HUGE_VAL;
    }}
    if (x < -7.45133219101941108420e+02) {{
        return 0.0;
    }}
    k = floor(x * 1.44269504088896338700e+00 + 0.5);
    hi = x - k * 6.93147180369123816490e-01;
    lo = k * 1.90821492927058770002e-10;
    r = hi - lo;
    t = r * r;
    c = r - t * (1.66666666666666019037e-01 + t * (-2.77777777770155933842e-03
        + t * (6.61375632143793436117e-05 + t * (-1.65339022054652515390e-06
        + t * 4.13813679705723846039e-08))));
    if (k == 0.0) {{
        return 1.0 - ((r * c) / (c - 2.0) - r);
    }}
    y = 1.0 - ((lo - (r * c) / (2.0 - c)) - hi);
    return ldexp(y, (int)k);
}}

static double {p}_expm1(double x)
{{
    double s = 1.0;
    int n;

    if (!(fabs(x) < 0.5)) {{
        return {p}_exp(x) - 1.0;
    }}
    for (n = 17; n > 1; --n) {{
        s = 1.0 + x / (double)n * s;
    }}
    return x * s;
}}

static double {p}_tanh(double x)
{{
    double ax, t, e;

    if (x != x || x == 0.0) {{
        return x;
    }}
    ax = fabs(x);
    if (ax >= 22.0) {{
        t = 1.0;
    }} else if (ax >= 1.0) {{
        t = 1.0 - 2.0 / ({p}_expm1(2.0 * ax) + 2.0);
    }} else {{
        e = {p}_expm1(-2.0 * ax);
        t = -e / (e + 2.0);
    }}
    return copysign(t, x);
}}
"""


def _rows(values: Sequence[float], fmt: Any, per_line: int = 3) -> str:
    items = [fmt(v) for v in values]
    return ",\n".join("    " + ", ".join(items[i:i + per_line])
                      for i in range(0, len(items), per_line))


def _float_literal(value: float) -> str:
    """A float literal of a float32 value (exact: its shortest double repr)."""
    return f"{c_double(value)}f"


def network_c_source(net: FirmwareNetwork, prefix: str | None = None) -> tuple[str, str]:
    """(header text, source text) of the network in C99: ``void
    <prefix>_policy_action(const float observation[], float action[])`` computes
    :func:`network_actions` of one row, bit for bit (and ``<prefix>_policy_output``
    the network's double output, :func:`network_outputs`), with no state, no
    allocation and no globals to initialise (the weights are constants).
    Compiles clean with ``-std=c99 -Wall -Wextra -Werror -pedantic``; link with
    ``-lm``."""
    p = check_prefix(default_prefix(net.entry) if prefix is None else prefix)
    macro = p.upper()
    n_in, n_out, layers = net.sizes[0], net.sizes[-1], len(net.sizes) - 1
    width = max(net.sizes)
    fn = f"{p}_policy_action"
    inputs = "\n".join(f" *   {i:3d}  {name}" + (f" = {net.constant_inputs[name]!r} (constant)"
                                                  if name in net.constant_inputs else "")
                       for i, name in enumerate(net.observation_names))
    units = ", ".join(f"{k} = {v!r}" for k, v in net.observation_units.items())
    outputs = "\n".join(f" *   {j}  {name}  (x {s!r})"
                        for j, (name, s) in enumerate(zip(net.action_names, net.action_scales)))
    post = ("unscaled from [-1, 1] to the action space, as SB3's squashed output" if net.squash
            else "clipped to the action space")
    header = f"""/*
 * {p}.h: the policy network of the learned entry "{net.entry}",
 * exported by stepdamp {__version__} (stepdamp export). Generated: re-export, do not edit.
 *
{c_comment(f"Call {fn} every 1/{macro}_DECISION_HZ s with the observation the benchmark's "
           f"env gives the entry, and hold the action until the next call. Network: "
           f"{'-'.join(map(str, net.sizes))} ({', '.join(net.activations)}), "
           f"{net.multiply_adds} multiply-adds per decision; every sum in input order in "
           "double, tanh fdlibm's; the output rounded to float, "
           f"{post}, then to [-1, 1]: the simulated policy's action bit for bit. Compile "
           "with -ffp-contract=off (no a*b + c fused into one rounding: gcc contracts by "
           "default in its GNU modes on FMA hardware; the source tells clang so). The "
           "observation as the benchmark's env gives it: each entry clipped to +-10, 0 "
           "where not finite, rounded to float.")}
 *
{c_comment(f"Units at the operating point exported ({net.motor}, {net.mode}, "
           f"{net.speed_rps!r} rev/s): {units}.")}
{c_comment(net.notes)}
 *
 * Inputs (float, in order):
{inputs}
 * Outputs (float in [-1, 1], in order; times the scale on the drive):
{outputs}
 */
#ifndef {macro}_H
#define {macro}_H

#define {macro}_N_OBSERVATION {n_in}
#define {macro}_N_ACTION {n_out}
#define {macro}_DECISION_HZ {c_double(net.decision_hz)}

extern const double {p}_action_scale[{macro}_N_ACTION];
/* The action (float in [-1, 1]) of one observation. */
void {fn}(const float observation[{macro}_N_OBSERVATION], float action[{macro}_N_ACTION]);
/* The network's output in double, before the rounding and clipping of the action. */
void {p}_policy_output(const float observation[{macro}_N_OBSERVATION],
        double output[{macro}_N_ACTION]);

#endif
"""
    codes = [ACTIVATIONS.index(a) for a in net.activations]
    uses_tanh = ACTIVATION.TANH in codes
    clamp = ("        v = low[o] + (0.5f * (v + 1.0f) * (high[o] - low[o]));\n" if net.squash
             else "        if (v < low[o]) {\n            v = low[o];\n        } else if (v > "
                  "high[o]) {\n            v = high[o];\n        }\n")
    source = f"""/* {p}.c: see {p}.h. Generated by stepdamp {__version__}: re-export, do not edit. */
#include <math.h>
#include "{p}.h"

/* No a*b + c fused into one rounding: gcc does not contract in ISO C mode
   (-std=c99) and ignores this pragma; clang honours it. */
#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF
#endif

#define {macro}_LAYERS {layers}
#define {macro}_WIDTH {width}

const double {p}_action_scale[{macro}_N_ACTION] = {{
{_rows(net.action_scales, c_double)}
}};

static const int sizes[{macro}_LAYERS + 1] = {{{", ".join(map(str, net.sizes))}}};
/* 0 identity, 1 relu, 2 tanh */
static const int activation[{macro}_LAYERS] = {{{", ".join(map(str, codes))}}};
static const float low[{macro}_N_ACTION] = {{{", ".join(map(_float_literal, net.action_low))}}};
static const float high[{macro}_N_ACTION] = {{{", ".join(map(_float_literal, net.action_high))}}};
static const double weights[{len(net.weights)}] = {{
{_rows(net.weights, c_double)}
}};
static const double biases[{len(net.biases)}] = {{
{_rows(net.biases, c_double)}
}};
{_TANH_C.format(p=p) if uses_tanh else ""}
void {p}_policy_output(const float observation[{macro}_N_OBSERVATION],
        double output[{macro}_N_ACTION])
{{
    double a[{macro}_WIDTH], z[{macro}_WIDTH], s;
    const double *w = weights;
    const double *b = biases;
    int layer, i, o;

    for (i = 0; i < {macro}_N_OBSERVATION; ++i) {{
        a[i] = (double)observation[i];
    }}
    for (layer = 0; layer < {macro}_LAYERS; ++layer) {{
        for (o = 0; o < sizes[layer + 1]; ++o) {{
            s = b[o];
            for (i = 0; i < sizes[layer]; ++i) {{
                s += w[i] * a[i];
            }}
            w += sizes[layer];
            if (activation[layer] == 1) {{
                s = s > 0.0 ? s : 0.0;
            }}{f''' else if (activation[layer] == 2) {{
                s = {p}_tanh(s);
            }}''' if uses_tanh else ""}
            z[o] = s;
        }}
        b += sizes[layer + 1];
        for (o = 0; o < sizes[layer + 1]; ++o) {{
            a[o] = z[o];
        }}
    }}
    for (o = 0; o < {macro}_N_ACTION; ++o) {{
        output[o] = a[o];
    }}
}}

void {fn}(const float observation[{macro}_N_OBSERVATION], float action[{macro}_N_ACTION])
{{
    double a[{macro}_N_ACTION];
    int o;
    float v;

    {p}_policy_output(observation, a);
    for (o = 0; o < {macro}_N_ACTION; ++o) {{
        v = (float)a[o];
{clamp}        if (v < -1.0f) {{
            v = -1.0f;
        }} else if (v > 1.0f) {{
            v = 1.0f;
        }}
        action[o] = v;
    }}
}}
"""
    return header, source
