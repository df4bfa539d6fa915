"""Where a report's numbers come from, stamped on the report, and the index built from stamps.

Every report a study writes ends with its :class:`Provenance`: the command, the commit
(``git describe --always --dirty``, the reports themselves left out of "dirty"), the versions of the packages that decide the numbers,
the seed (every random draw derives from it; per trial, see each study's module), the
trials, the wall time, the machine's cores and Python. It is written twice: as markdown for
the reader, and as one machine-readable line (an HTML comment, invisible when rendered)
from which :func:`index_lines` builds ``reports/index.md``. The index is never edited by
hand: it lists what the reports themselves say, and says so when they do not come from one
clean commit.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from importlib import metadata
from pathlib import Path

#: the packages whose versions decide a study's numbers (distribution names)
PACKAGES = ("casadi", "pin", "coal", "numpy", "scipy", "open3d", "ruckig", "ur-analytic-ik")
MARKER = "<!-- provenance "
REPO = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class Provenance:
    """The facts of one study run: ``command`` as typed, ``commit`` (``git describe``),
    ``seed``, ``trials``, wall time ``seconds`` (s), ``cores``, ``python`` and ``packages``
    ((distribution, version) pairs)."""

    command: str
    commit: str
    seed: int
    trials: int
    seconds: float
    cores: int
    python: str
    packages: tuple[tuple[str, str], ...]

    def lines(self) -> list[str]:
        """The report's provenance section (markdown), ending with the machine line."""
        packages = ", ".join(f"{n} {v}" for n, v in self.packages)
        doc = asdict(self) | {"packages": dict(self.packages)}
        machine = json.dumps(doc, sort_keys=True).replace(">", "\\u003e")  # no '-->' inside
        return ["", "## Provenance", "",
                f"- command: `{self.command}`",
                f"- commit: {self.commit}",
                f"- seed {self.seed} (every random draw derives from it), "
                f"trials {self.trials}, wall time {self.seconds:.1f} s on {self.cores} cores "
                f"(Python {self.python})",
                f"- packages: {packages}", "",
                f"{MARKER}{machine} -->", ""]  # fmt: skip

    @classmethod
    def from_line(cls, line: str) -> Provenance:
        """The provenance of a machine line written by :meth:`lines` (ValueError if not)."""
        if not (line.startswith(MARKER) and line.rstrip().endswith("-->")):
            raise ValueError(f"not a provenance line: {line[:60]!r}")
        d = json.loads(line[len(MARKER) : line.rstrip().rindex("-->")])
        return cls(str(d["command"]), str(d["commit"]), int(d["seed"]), int(d["trials"]),
                   float(d["seconds"]), int(d["cores"]), str(d["python"]),
                   tuple((str(k), str(v)) for k, v in d["packages"].items()))  # fmt: skip


def git_describe(folder: Path = REPO) -> str:
    """``git describe --always --abbrev=12`` of the checkout, ``-dirty`` appended when a
    tracked file outside ``reports/`` differs from the commit (the reports are the outputs:
    ``make report`` rewrites them while it runs), or ``not a git checkout``."""
    try:
        head = subprocess.run(["git", "describe", "--always", "--abbrev=12"], cwd=folder,
                              capture_output=True, text=True, timeout=10, check=True)  # fmt: skip
        changes = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no", "--", ".", ":(exclude)reports"],
            cwd=folder, capture_output=True, text=True, timeout=10, check=True)  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return "not a git checkout"
    return head.stdout.strip() + ("-dirty" if changes.stdout.strip() else "")


def version(name: str) -> str:
    """The installed version of distribution ``name``, or ``not installed``."""
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "not installed"


def collect(command: str, trials: int, seed: int, seconds: float) -> Provenance:
    """The provenance of a run that just took ``seconds`` (s), from this process."""
    return Provenance(command, git_describe(), seed, trials, round(seconds, 1),
                      os.cpu_count() or 1, platform.python_version(),
                      tuple((n, version(n)) for n in PACKAGES))  # fmt: skip


def stamp(report: Path, command: str, trials: int, seed: int, seconds: float) -> Provenance:
    """Append the provenance of this run to an existing ``report`` (nothing if absent)."""
    prov = collect(command, trials, seed, seconds)
    if report.is_file():
        report.write_text(report.read_text().rstrip("\n") + "\n" + "\n".join(prov.lines()))
    return prov


def read_stamp(report: Path) -> Provenance | None:
    """The provenance a report ends with (its last machine line), or None."""
    if not report.is_file():
        return None
    lines = [ln for ln in report.read_text().splitlines() if ln.startswith(MARKER)]
    try:
        return Provenance.from_line(lines[-1]) if lines else None
    except (ValueError, KeyError, TypeError):
        return None


def index_lines(out: Path, names: Sequence[str]) -> list[str]:
    """``index.md`` of the reports ``out/<name>/report.md``, from their stamps alone."""
    stamps = {name: read_stamp(out / name / "report.md") for name in names}
    found = [p for p in stamps.values() if p is not None]
    commits = sorted({p.commit for p in found})
    packages = sorted({p.packages for p in found})
    lines = ["# beamrelay studies", "",
             "Generated from the reports' own provenance stamps by `beamrelay study all` "
             "(regenerate everything with `make report`); do not edit by hand. Each folder "
             "has report.md (our figures next to the paper's), CSV of the raw numbers and "
             "PNG plots.", ""]  # fmt: skip
    clean = len(commits) == 1 and not commits[0].endswith("-dirty") and len(found) == len(names)
    if clean and len(packages) == 1:
        lines.append(f"Every report comes from commit {commits[0]}, with the same packages: "
                     + ", ".join(f"{n} {v}" for n, v in packages[0]) + ".")  # fmt: skip
    else:
        missing = [n for n, p in stamps.items() if p is None]
        lines.append("**The reports do not come from one clean run:** "
                     f"commits {', '.join(commits) or 'none'}; "
                     f"{len(packages)} package set(s); "
                     f"without a stamp: {', '.join(missing) or 'none'}.")  # fmt: skip
    lines += ["", "| study | report | commit | seed | trials | wall time (s) | cores | command |",
              "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for name, p in stamps.items():
        link = f"[{name}/report.md]({name}/report.md)"
        if p is None:
            lines.append(f"| {name} | {link} | no stamp | - | - | - | - | - |")
            continue
        lines.append(f"| {name} | {link} | {p.commit} | {p.seed} | {p.trials} | "
                     f"{p.seconds:.0f} | {p.cores} | `{p.command}` |")  # fmt: skip
    return [*lines, ""]


def write_index(out: Path, names: Sequence[str]) -> Path:
    """Write ``out/index.md`` (:func:`index_lines`); returns its path."""
    path = out / "index.md"
    path.write_text("\n".join(index_lines(out, names)))
    return path
