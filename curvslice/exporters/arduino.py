"""The Arduino AccelStepper sketch driving syringe extruders from controller signals (seed 003).

The robot controller shows pattern k of :func:`curvslice.exporters.vplus.speed_inventory` as the
binary number k on its signals; the Arduino reads the same lines on ``input_pins`` and runs the
pattern's extruder at the stepper speed of the syringe flow model (:mod:`curvslice.flow`):
plunger speed = nozzle speed × r_nozzle²/r_syringe², steps/s = plunger mm/s ÷ mm per step.
With one signal the sketch is the seed's own listing.
"""

from __future__ import annotations

import re
from pathlib import Path

from curvslice import flow
from curvslice.cell.cells import Syringe
from curvslice.errors import CurvsliceError
from curvslice.validate import require_finite

_BRANCH = re.compile(r"else if \(([^)]*)\)\s*\{\s*//\s*Extruder (\d+), Speed (\d+)\s*\n\s*E\d+\.setSpeed\(([-+0-9.eE]+)\)")
_CONDITION = re.compile(r"IN(\d+) == (HIGH|LOW)")


def pattern_steps(patterns: list[tuple[int, float]], syringe: Syringe) -> list[float]:
    """Stepper speed (steps/s) of each (extruder, nozzle speed mm/s) pattern."""
    plunger = flow.plunger_speed([s for _, s in patterns], syringe.nozzle_to_syringe_radius, 1.0)
    steps = flow.steps_per_second(plunger, syringe.inch_per_step * flow.MM_PER_INCH)
    too_fast = [(p, s) for p, s in zip(patterns, steps) if s > syringe.max_steps_per_second]
    if too_fast:
        (tool, speed), s = too_fast[0]
        raise CurvsliceError(
            f"extruder {tool} at {speed:g} mm/s needs {s:.1f} steps/s, above the stepper maximum "
            f"{syringe.max_steps_per_second:g} (syringe.max_steps_per_second)"
        )
    return [float(s) for s in steps]


def write_accelstepper_sketch(path: Path, patterns: list[tuple[int, float]], bits: int, syringe: Syringe) -> None:
    """Write the ``.ino`` sketch decoding ``bits`` input pins into the patterns' stepper speeds."""
    require_finite("Arduino sketch writer", speed=[s for _, s in patterns] or [0.0],
                   syringe=[syringe.nozzle_to_syringe_radius, syringe.inch_per_step, syringe.max_steps_per_second])
    if bits > len(syringe.input_pins):
        raise CurvsliceError(f"{bits} signal lines needed but only {len(syringe.input_pins)} Arduino input pins listed")
    tools = sorted({t for t, _ in patterns}) or [0]
    if tools[-1] >= len(syringe.motor_pins):
        raise CurvsliceError(f"extruder T{tools[-1]} has no motor pins in syringe.motor_pins")
    steps = pattern_steps(patterns, syringe)
    out = ["#include <AccelStepper.h>", ""]
    out += [f"#define D{b + 1}_SIGNAL_PIN    {syringe.input_pins[b]}" for b in range(bits)]
    out.append("")
    for t in tools:
        step, direction, enable = syringe.motor_pins[t]
        out += [f"#define E{t}_STEP_PIN      {step}", f"#define E{t}_DIR_PIN       {direction}",
                f"#define E{t}_ENABLE_PIN    {enable}", ""]
    out += [f"AccelStepper E{t}(AccelStepper::DRIVER, E{t}_STEP_PIN, E{t}_DIR_PIN);" for t in tools]
    out += ["", "void setup()", "{", "    Serial.begin(9600);", ""]
    out += [f"    pinMode(D{b + 1}_SIGNAL_PIN, INPUT);    // Speed Pin" for b in range(bits)]
    for t in tools:
        out += ["", f"    pinMode(E{t}_STEP_PIN, OUTPUT);", f"    pinMode(E{t}_DIR_PIN, OUTPUT);",
                f"    pinMode(E{t}_ENABLE_PIN, OUTPUT);"]
    out.append("")
    out += [f"    digitalWrite(E{t}_ENABLE_PIN, LOW);" for t in tools]
    out.append("")
    out += [f"    E{t}.setMaxSpeed({syringe.max_steps_per_second:g});" for t in tools]
    out += ["}", "", "void loop()", "{"]
    out += [f"    int IN{b} = digitalRead(D{b + 1}_SIGNAL_PIN);" for b in range(bits)]

    def condition(code: int) -> str:
        return " && ".join(f"IN{b} == {'HIGH' if (code >> b) & 1 else 'LOW'}" for b in range(bits))

    out += ["", f"    if ({condition(0)}) {{", "        // motor does not move", "    }"]
    rank: dict[int, int] = {}
    for code, ((tool, _), s) in enumerate(zip(patterns, steps), start=1):
        rank[tool] = rank.get(tool, 0) + 1
        out += [f"    else if ({condition(code)}) {{    // Extruder {tool}, Speed {rank[tool]}",
                f"        E{tool}.setSpeed({s:.12g});", f"        E{tool}.runSpeed();", "    }"]
    out.append("}")
    Path(path).write_text("\n".join(out) + "\n")


def read_accelstepper_sketch(path: Path) -> dict[int, tuple[int, float]]:
    """Pattern code → (extruder, steps/s) of a sketch written by :func:`write_accelstepper_sketch`."""
    table = {}
    for m in _BRANCH.finditer(Path(path).read_text()):
        code = sum(1 << int(b) for b, level in _CONDITION.findall(m[1]) if level == "HIGH")
        table[code] = (int(m[2]), float(m[4]))
    return table
