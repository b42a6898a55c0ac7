"""ABB RAPID programs (joint-space trajectories and Cartesian robtarget paths; seeds 000 and 004).

Large programs are split into modules of at most ``max_targets`` targets (seed 004, §2.3.1:
the controller heap holds ~15,000 coordinates, so modules of ≤ 7,000 let two fit at once) and
a main module loads, runs and unloads them in order with late-bound calls (seed 004, Fig. 30).
Moves blend through zones; ``fine`` (a full stop) is used only where an output must switch at
an exact point and at the end of each module (seed 004, §2.4.4: ``fine`` everywhere stops the
robot at every point).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from curvslice.errors import CurvsliceError
from curvslice.exporters import chunks, clean_outdir, joint_program, relative_times

_IDENT = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,19}")
_NUM = r"[-+0-9.eE]+"
_JOINTTARGET = re.compile(rf"CONST\s+jointtarget\s+(\w+)\s*:=\s*\[\[([^\]]*)\]")
_MOVEABSJ = re.compile(rf"^\s*MoveAbsJ\s+(\w+)\s*,\s*\w+(?:\\T:=({_NUM}))?")
_SETDO = re.compile(r"^\s*SetDO\s+(\w+)\s*,\s*([01])\s*;")
_COMMENT_NUMBER = re.compile(rf"^\s*!\s*(t_start|segment)\s+({_NUM})")
_LOAD = re.compile(r'Load\s+\\Dynamic\s*,\s*"[^"]*?([^"/:]+)\.mod"', re.IGNORECASE)
_NINES = "[9E9,9E9,9E9,9E9,9E9,9E9]"


def check_identifier(name: str) -> str:
    """``name`` if it can prefix RAPID module/routine names (letter first, ≤ 20 characters)."""
    if not _IDENT.fullmatch(name):
        raise CurvsliceError(
            f"program name {name!r} is not usable in RAPID: use a letter then letters, digits or _ (≤ 20 characters)"
        )
    return name


def write_main_module(outdir: Path, name: str, parts: int, load_dir: str, reset: list[str]) -> Path:
    """The main module: reset outputs, then Load \\Dynamic, call and UnLoad each part in order."""
    lines = [f"MODULE {name}_main", "  PROC main()", "    ConfJ \\Off;", "    ConfL \\Off;"]
    lines += [f"    {r}" for r in reset]
    for k in range(1, parts + 1):
        lines += [
            f'    Load \\Dynamic, "{load_dir}{name}_mod{k}.mod";',
            f'    %"{name}_part{k}"%;',
            f'    UnLoad "{load_dir}{name}_mod{k}.mod";',
        ]
    lines += [f"    {r}" for r in reset]
    lines += ["  ENDPROC", "ENDMODULE"]
    path = outdir / f"{name}_main.mod"
    path.write_text("\n".join(lines) + "\n")
    return path


def ordered_modules(paths: Sequence[Path]) -> list[Path]:
    """Part modules in run order: the main module's Load order if it is given, else as given."""
    paths = [Path(p) for p in paths]
    mains = [p for p in paths if p.stem.endswith("_main")]
    parts = [p for p in paths if not p.stem.endswith("_main")]
    if not mains:
        return parts
    by_stem = {p.stem.lower(): p for p in parts}
    order = [m.lower() for m in _LOAD.findall(mains[0].read_text())]
    missing = [s for s in order if s not in by_stem]
    if missing:
        raise CurvsliceError(f"main module loads {missing[0]}.mod, which is not among the given files")
    return [by_stem[s] for s in order]


def write_rapid_joints(
    outdir: Path,
    q: np.ndarray,
    t: np.ndarray,
    *,
    segment: np.ndarray | None = None,
    extruding: np.ndarray | None = None,
    max_targets: int = 7000,
    name: str = "curvslice",
    extruder_signal: str = "doExtruder",
    zone: str = "z1",
    approach_speed: str = "v100",
    load_dir: str = "HOME:/",
) -> list[Path]:
    """Write ``name_main.mod`` + ``name_mod1.mod …`` (≤ ``max_targets`` jointtargets each).

    Returns ``[main, mod1, mod2, …]``. Row i is a ``MoveAbsJ`` lasting exactly ``t[i] - t[i-1]``
    (``\\T``); joint angles are written in degrees. ``extruding[i]`` sets ``extruder_signal``
    before the move to row i, after a ``fine`` stop so the switch happens at the point. A new
    ``segment`` value also ends the previous motion with ``fine``.
    """
    q, t, seg, ext = joint_program(q, t, segment, extruding)
    check_identifier(name)
    dt = relative_times(t)
    deg = np.degrees(q)
    outdir = Path(outdir)
    clean_outdir(outdir, f"{name}_mod*.mod")
    n = len(q)
    # stop after the untimed approach, where the next row switches the extruder or starts a new
    # segment, and where a module ends
    stop = np.ones(n, bool)
    stop[:-1] = (ext[1:] != ext[:-1]) | (seg[1:] != seg[:-1])
    stop[0] = True
    parts = chunks(n, max_targets)
    paths = []
    for k, rows in enumerate(parts, start=1):
        stop[rows.stop - 1] = True
        lines = [
            f"MODULE {name}_mod{k}",
            f"  ! curvslice joint program part {k} of {len(parts)}, rows {rows.start}..{rows.stop - 1}",
            f"  ! t_start {float(t[rows.start])!r}",
        ]
        lines += [
            f"  LOCAL CONST jointtarget j{i} := [[{','.join(f'{v:.6f}' for v in deg[i])}],{_NINES}];" for i in rows
        ]
        lines.append(f"  PROC {name}_part{k}()")
        for i in rows:
            first = i == rows.start
            if first or seg[i] != seg[i - 1]:
                lines.append(f"    ! segment {seg[i]}")
            if first or ext[i] != ext[i - 1]:
                lines.append(f"    SetDO {extruder_signal}, {int(ext[i])};")
            z = "fine" if stop[i] else zone
            speed = approach_speed if i == 0 else f"v1000\\T:={dt[i]:.9f}"
            lines.append(f"    MoveAbsJ j{i}, {speed}, {z}, tool0;")
        lines += ["  ENDPROC", "ENDMODULE"]
        path = outdir / f"{name}_mod{k}.mod"
        path.write_text("\n".join(lines) + "\n")
        paths.append(path)
    main = write_main_module(outdir, name, len(parts), load_dir, [f"SetDO {extruder_signal}, 0;"])
    return [main, *paths]


def read_rapid_joints(paths: Sequence[Path]) -> dict[str, np.ndarray]:
    """Read modules of :func:`write_rapid_joints` back to ``q`` (rad), ``t``, ``segment``, ``extruding``.

    ``paths`` may include the main module (its Load order is then used) or list the part
    modules in run order.
    """
    q, t, seg, ext = [], [], [], []
    for path in ordered_modules(paths):
        text = path.read_text()
        targets = {m[1]: [float(v) for v in m[2].split(",")] for m in _JOINTTARGET.finditer(text)}
        t_file, rel = None, None
        segment, state = 0, False
        for line in text.splitlines():
            if m := _COMMENT_NUMBER.match(line):
                if m[1] == "t_start":
                    t_file = float(m[2])
                else:
                    segment = int(m[2])
            elif m := _SETDO.match(line):
                state = m[2] == "1"
            elif m := _MOVEABSJ.match(line):
                if t_file is None:
                    raise CurvsliceError(f"{path}: motion before the '! t_start' header; not a curvslice joint module")
                if m[1] not in targets:
                    raise CurvsliceError(f"{path}: MoveAbsJ to undeclared jointtarget {m[1]}")
                rel = 0.0 if rel is None else rel + float(m[2])
                q.append(targets[m[1]])
                t.append(t_file + rel)
                seg.append(segment)
                ext.append(state)
    if not q:
        raise CurvsliceError("no MoveAbsJ motion found in the RAPID modules")
    return {
        "q": np.radians(np.asarray(q, dtype=np.float64)),
        "t": np.asarray(t, dtype=np.float64),
        "segment": np.asarray(seg, dtype=np.int64),
        "extruding": np.asarray(ext, dtype=bool),
    }
