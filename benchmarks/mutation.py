"""How many plausible bugs do the tests catch? Mutation testing of the code that decides outcomes, per module.

mutmut (3.x) plants one small bug (a *mutant*) at a time in a copy of the package: an operator swapped
(``<`` for ``<=``, ``+`` for ``-``), a constant changed by one, an argument dropped or set to None, a string
changed. For each mutant it runs the tests that execute the changed function and records whether one failed
(*killed*) or all passed (*survived*). A survivor is a bug of that kind no test would notice.

The groups, the functions mutated in each and the tests that own them are in ``pyproject.toml`` under
``[tool.dyndlo-vision.mutation]``. mutmut reads its configuration from the working directory, so each group
runs in its own copy of the repository (``build/mutation/<group>``, kept for ``mutmut browse``/``show``
there) with that group's mutmut settings: a group's mutants meet only that group's tests.

Survivors that no test can kill because they behave exactly as the original (*equivalent*), and survivors a
user cannot notice (*harmless*: a log line, a message, a comparison where two floats tie to the last bit) are
listed with a one-line reason in ``benchmarks/mutation_survivors.toml``. The score of a group is
killed / (mutants - equivalent); harmless survivors count as not killed. Every other survivor is printed
(``--show``: with its diff; ``--skeleton``: as entries for that file).

    python benchmarks/mutation.py                      # every group, one after the other
    python benchmarks/mutation.py --group trajectory   # one group
    python benchmarks/mutation.py --quick              # the smoke part CI runs (a test runs it)
    python benchmarks/mutation.py --json out.json      # also write the figures

The script lowers its own priority (``nice``) and limits numeric threads to one per process; ``--jobs``
(default 2) mutants run at a time. Needs ``pip install -e ".[test]"`` (mutmut is a test dependency).
"""

from __future__ import annotations

import argparse
import fnmatch
import hashlib
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import textwrap
import time
import tomllib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SURVIVORS_FILE = ROOT / "benchmarks" / "mutation_survivors.toml"
STATUS = {  # mutmut's exit codes (mutmut.stats.status_by_exit_code)
    1: "killed", 3: "killed", 0: "survived", 5: "no tests", 33: "no tests", 34: "skipped",
    36: "timeout", 24: "timeout", -24: "timeout", 152: "timeout", 255: "timeout", -11: "segfault",
    -9: "segfault", 37: "type check", None: "not checked",
}  # fmt: skip
#: Statuses that mean a test noticed the mutant (a timeout: the tests ran far longer than unmutated).
DETECTED = {"killed", "timeout", "segfault"}
#: The helper that prints the diff of each named mutant, run inside a group's working directory.
DIFF_HELPER = textwrap.dedent(
    """
    import json, sys
    from mutmut.mutation.diff_apply import get_diff_for_mutant
    out = {}
    for name, path in json.loads(sys.stdin.read()):
        out[name] = get_diff_for_mutant(name, path=path)
    print(json.dumps(out))
    """
)


@dataclass
class Group:
    """One group of the configuration: files (each with function patterns) and the tests that own them."""

    name: str
    mutate: dict[str, list[str]]
    tests: list[str]
    description: str = ""
    #: mutmut's wall-clock limit per mutant is this times the tests' own time (plus 1 s); mutmut's default 15.
    timeout_multiplier: float = 15.0

    def mutant_globs(self) -> list[str]:
        """mutmut's names for the functions of :attr:`mutate` (``mod.x_func__mutmut_3``,
        ``mod.xǁClassǁmethod__mutmut_3``), as fnmatch patterns."""
        globs = []
        for path, functions in self.mutate.items():
            module = path.removesuffix(".py").replace("/", ".")
            for spec in functions:
                if spec == "*":
                    globs.append(f"{module}.*")
                elif "." in spec:
                    cls, method = spec.split(".", 1)
                    globs.append(f"{module}.xǁ{cls}ǁ{method}__mutmut_*")
                else:
                    globs.append(f"{module}.x_{spec}__mutmut_*")
        return globs


@dataclass
class Result:
    """Outcome of one group's run."""

    group: str
    seconds: float
    status: dict[str, str] = field(default_factory=dict)  # mutant name -> status
    path: dict[str, str] = field(default_factory=dict)  # mutant name -> source path
    diffs: dict[str, str] = field(default_factory=dict)  # survivors' diffs


def load_groups(pyproject: Path = ROOT / "pyproject.toml") -> dict[str, Group]:
    """The groups of ``[tool.dyndlo-vision.mutation]`` (the ``quick`` group is CI's smoke part)."""
    data = tomllib.loads(pyproject.read_text(encoding="utf-8"))
    table = data.get("tool", {}).get("dyndlo-vision", {}).get("mutation", {})
    if not table:
        raise SystemExit(f"{pyproject}: no [tool.dyndlo-vision.mutation] table")
    groups = {}
    for name, entry in table.items():
        mutate = entry.get("mutate")
        tests = entry.get("tests")
        if not isinstance(mutate, dict) or not mutate or not isinstance(tests, list) or not tests:
            raise SystemExit(
                f"{pyproject}: mutation group {name!r} needs a 'mutate' table and 'tests', got {entry!r}"
            )
        for path in mutate:
            if not (ROOT / path).is_file():
                raise SystemExit(f"{pyproject}: mutation group {name!r} names {path!r}, which is not a file")
        groups[name] = Group(name, {k: list(v) for k, v in mutate.items()}, list(tests),
                             entry.get("description", ""), float(entry.get("timeout_multiplier", 15.0)))
    return groups


def mutmut_section(group: Group) -> str:
    """The ``[tool.mutmut]`` table of a group's working copy."""
    lines = [
        "[tool.mutmut]",
        'source_paths = ["dyndlo_vision"]',
        'also_copy = ["examples"]',
        f"only_mutate = {json.dumps(sorted(group.mutate))}",
        f"pytest_add_cli_args_test_selection = {json.dumps(group.tests)}",
        # The plugins that could reorder or cache tests are off; the project's warnings filter stays.
        'pytest_add_cli_args = ["-p", "no:cacheprovider", "-p", "no:xdist"]',
        f"timeout_multiplier = {group.timeout_multiplier}",
    ]
    return "\n".join(lines) + "\n"


def without_table(text: str, header: str) -> str:
    """``text`` (a TOML document) without the table ``[header]`` and its sub-tables."""
    out, skipping = [], False
    for line in text.splitlines(keepends=True):
        stripped = line.strip()
        if stripped.startswith("["):
            name = stripped.strip("[]").strip()
            skipping = name == header or name.startswith(header + ".")
        if not skipping:
            out.append(line)
    return "".join(out)


def prepare(group: Group, workdir: Path) -> None:
    """A fresh copy of the package and the tests in ``workdir`` with the group's mutmut settings."""
    if workdir.exists():
        shutil.rmtree(workdir)
    workdir.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", ".pytest_cache")
    for name in ("dyndlo_vision", "tests", "examples"):  # examples: the run configurations tests read
        shutil.copytree(ROOT / name, workdir / name, ignore=ignore)
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    for header in ("tool.mutmut", "tool.dyndlo-vision"):
        text = without_table(text, header)
    (workdir / "pyproject.toml").write_text(text.rstrip() + "\n\n" + mutmut_section(group), encoding="utf-8")
    # The tests find the optional external data at ../shared beside the repository (tests/conftest.py); mutmut
    # runs them from workdir/mutants, so workdir/shared must lead there.
    shared = ROOT.parent / "shared"
    if shared.exists():
        (workdir / "shared").symlink_to(shared.resolve())


def package_digest(root: Path) -> str:
    """A hash of the package's Python files under ``root`` (is a working copy still current?)."""
    h = hashlib.sha256()
    for path in sorted((root / "dyndlo_vision").rglob("*.py")):
        h.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes())
    return h.hexdigest()


def run_mutmut(group: Group, workdir: Path, names: list[str], jobs: int, log: Path) -> float:
    """``mutmut run`` on the named mutants (fnmatch patterns) in ``workdir``; returns the wall time."""
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    env.pop("CI", None)  # under CI a skipped test fails (tests/conftest.py); mutmut's forced-fail run skips
    cmd = [sys.executable, "-m", "mutmut", "run", "--max-children", str(jobs), *names]
    t0 = time.monotonic()
    with log.open("a", encoding="utf-8") as out:
        proc = subprocess.run(cmd, cwd=workdir, env=env, stdout=out, stderr=subprocess.STDOUT, check=False)
    if proc.returncode != 0:
        tail = log.read_text(encoding="utf-8", errors="replace").replace("\r", "\n")[-3000:]
        raise SystemExit(f"mutmut failed for group {group.name!r} (exit {proc.returncode}); {log}:\n{tail}")
    return time.monotonic() - t0


def read_results(group: Group, workdir: Path, seconds: float) -> Result:
    """Every selected mutant's status from the working copy, with the diffs of those not detected."""
    result = Result(group.name, seconds)
    globs = group.mutant_globs()
    for meta in sorted((workdir / "mutants").rglob("*.py.meta")):
        source = str(meta.relative_to(workdir / "mutants")).removesuffix(".meta")
        codes = json.loads(meta.read_text(encoding="utf-8"))["exit_code_by_key"]
        for name, code in codes.items():
            if any(fnmatch.fnmatchcase(name, g) for g in globs):
                result.status[name] = STATUS.get(code, "suspicious")
                result.path[name] = source
    undetected = [n for n, s in result.status.items() if s not in DETECTED]
    if undetected:
        helper = subprocess.run([sys.executable, "-c", DIFF_HELPER], cwd=workdir, check=True,
                                input=json.dumps([[n, result.path[n]] for n in undetected]),
                                capture_output=True, text=True)
        result.diffs = json.loads(helper.stdout)
    return result


def run_group(group: Group, workdir: Path, jobs: int, log: Path, mode: str) -> Result:
    """One group: a fresh run (``mode="fresh"``), a re-run of the undetected mutants against the current
    tests (``"resume"``), or only the figures of the last run (``"report"``)."""
    if mode == "fresh":
        prepare(group, workdir)
        log.write_text("", encoding="utf-8")
        return read_results(group, workdir, run_mutmut(group, workdir, group.mutant_globs(), jobs, log))
    if not (workdir / "mutants").is_dir():
        raise SystemExit(f"no earlier run of group {group.name!r} in {workdir}: run it without --{mode}")
    if package_digest(workdir) != package_digest(ROOT):
        raise SystemExit(f"the package changed since group {group.name!r} ran in {workdir}: run it afresh")
    if mode == "report":
        return read_results(group, workdir, 0.0)
    # Tests only added or strengthened cannot revive a killed mutant, so only the others are run again.
    undetected = [n for n, s in read_results(group, workdir, 0.0).status.items() if s not in DETECTED]
    shutil.rmtree(workdir / "tests")
    shutil.copytree(ROOT / "tests", workdir / "tests", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    seconds = run_mutmut(group, workdir, undetected, jobs, log) if undetected else 0.0
    return read_results(group, workdir, seconds)


def readable(name: str) -> tuple[str, str]:
    """(module, function) of a mutant name: ``mod.xǁClsǁf__mutmut_3`` -> (``mod``, ``Cls.f``)."""
    base = name.rsplit("__mutmut_", 1)[0]
    module, _, func = base.rpartition(".x")
    if func.startswith("ǁ"):
        func = func.strip("ǁ").replace("ǁ", ".")
    else:
        func = func.removeprefix("_")
    return module, func


def mutant_key(name: str, diff: str) -> str:
    """The key of a survivor in ``mutation_survivors.toml``: its function, its line(s) before and after.

    Stable while the function's code is: mutmut numbers mutants per function, so a key by number would point
    at another mutant after an unrelated edit above it in the same function.
    """
    _, func = readable(name)
    lines = diff.splitlines()
    removed = [ln[1:].strip() for ln in lines if ln.startswith("-") and not ln.startswith("---")]
    added = [ln[1:].strip() for ln in lines if ln.startswith("+") and not ln.startswith("+++")]
    before, after = (re.sub(r"\s+", " ", " / ".join(part)) for part in (removed, added))
    return f"{func}: {before} -> {after}"


def load_survivors() -> dict[str, dict[str, tuple[str, str]]]:
    """``{source path: {key: (kind, reason)}}`` from ``mutation_survivors.toml``."""
    if not SURVIVORS_FILE.exists():
        return {}
    data = tomllib.loads(SURVIVORS_FILE.read_text(encoding="utf-8"))
    out: dict[str, dict[str, tuple[str, str]]] = {}
    for path, entries in data.items():
        for key, text in entries.items():
            kind, _, reason = text.partition(":")
            if kind not in ("equivalent", "harmless") or not reason.strip():
                raise SystemExit(f"{SURVIVORS_FILE}: [{path!r}] {key!r} must read 'equivalent: why' or "
                                 f"'harmless: why', got {text!r}")
            out.setdefault(path, {})[key] = (kind, reason.strip())
    return out


def score(result: Result, survivors: dict[str, dict[str, tuple[str, str]]]) -> dict[str, object]:
    """Per-file and total figures of one group, with the unexplained survivors and stale explanations."""
    files: dict[str, Counter[str]] = {}
    unexplained: list[tuple[str, str, str]] = []
    used: set[tuple[str, str]] = set()
    for name, status in result.status.items():
        path = result.path[name]
        counts = files.setdefault(path, Counter())
        counts["mutants"] += 1
        counts[status] += 1
        if status in DETECTED:
            continue
        key = mutant_key(name, result.diffs.get(name, ""))
        explained = survivors.get(path, {}).get(key)
        if explained is None:
            unexplained.append((path, key, result.diffs.get(name, "")))
            continue
        used.add((path, key))
        counts[explained[0]] += 1
    stale = [(p, k) for p, entries in survivors.items() if p in files for k in entries if (p, k) not in used]
    rows = {}
    for path, c in sorted(files.items()):
        detected = sum(c[s] for s in DETECTED)
        scored = c["mutants"] - c["equivalent"]
        rows[path] = {
            "mutants": c["mutants"], "killed": c["killed"], "timeout": c["timeout"] + c["segfault"],
            "survived": c["survived"], "no_tests": c["no tests"], "equivalent": c["equivalent"],
            "harmless": c["harmless"], "score": detected / scored if scored else 1.0,
        }  # fmt: skip
    total = Counter()
    for row in rows.values():
        total.update({k: v for k, v in row.items() if k != "score"})
    scored = total["mutants"] - total["equivalent"]
    detected = total["killed"] + total["timeout"]
    return {"files": rows, "total": {**total, "score": detected / scored if scored else 1.0},
            "unexplained": unexplained, "stale": stale, "seconds": result.seconds}


def toml_string(text: str) -> str:
    """``text`` as a TOML basic string."""
    return json.dumps(text, ensure_ascii=False)


def print_report(group: Group, figures: dict[str, object], show: bool, skeleton: bool = False) -> None:
    print(f"\n## {group.name}: {figures['seconds'] / 60:.1f} min")
    print("| file | mutants | killed | timeout | survived | no tests | equivalent | harmless | score |")
    print("|---|---|---|---|---|---|---|---|---|")
    rows = dict(figures["files"])
    rows["total"] = figures["total"]
    for path, r in rows.items():
        keys = ("mutants", "killed", "timeout", "survived", "no_tests", "equivalent", "harmless")
        cells = [r[k] for k in keys]
        print(f"| {path} | " + " | ".join(str(c) for c in cells) + f" | {100 * r['score']:.1f} % |")
    unexplained = figures["unexplained"]
    if unexplained:
        print(f"\n{len(unexplained)} unexplained survivor(s):")
        for path, key, diff in unexplained:
            print(f"  {path}  {key}")
            if show:
                print(textwrap.indent(diff, "      "))
    for path, key in figures["stale"]:
        print(f"  stale entry in {SURVIVORS_FILE.name} (no surviving mutant has it): [{path!r}] {key!r}")
    if skeleton and unexplained:
        print(f"\n# Entries for {SURVIVORS_FILE.name}, reasons to fill in:")
        for path in sorted({p for p, _, _ in unexplained}):
            print(f"\n[{toml_string(path)}]")
            for _, key, _ in (u for u in unexplained if u[0] == path):
                print(f"{toml_string(key)} = \"equivalent: \"")


def main() -> None:
    raw = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=raw)
    parser.add_argument("--group", action="append", help="group to run (repeatable; default: all but quick)")
    parser.add_argument("--quick", action="store_true", help="run the 'quick' group only (CI's smoke part)")
    parser.add_argument("--jobs", type=int, default=2, help="mutants tested at a time (default 2)")
    parser.add_argument("--workdir", type=Path, default=ROOT / "build" / "mutation",
                        help="where the groups' working copies go (default build/mutation)")
    parser.add_argument("--resume", action="store_true",
                        help="re-run only the mutants the group's last run did not detect, against the "
                        "current tests (valid when tests were only added or strengthened, the package "
                        "unchanged)")
    parser.add_argument("--report", action="store_true", help="no run: the figures of each group's last run")
    parser.add_argument("--show", action="store_true", help="print the diff of every unexplained survivor")
    parser.add_argument("--skeleton", action="store_true",
                        help="print the unexplained survivors as entries for mutation_survivors.toml")
    parser.add_argument("--json", type=Path, default=None, help="write the figures to this JSON file")
    parser.add_argument("--min-score", type=float, default=None,
                        help="exit 1 when a group scores below this fraction (e.g. 0.9)")
    parser.add_argument("--strict", action="store_true",
                        help="exit 1 when a survivor is unexplained or an explanation is stale")
    args = parser.parse_args()
    if args.jobs < 1:
        parser.error(f"--jobs must be >= 1, got {args.jobs}")

    groups = load_groups()
    if args.quick:
        names = ["quick"]
    elif args.group:
        names = args.group
    else:
        names = [n for n in groups if n != "quick"]
    unknown = [n for n in names if n not in groups]
    if unknown:
        parser.error(f"unknown group(s) {unknown}; the groups are {sorted(groups)}")
    if hasattr(os, "nice"):
        os.nice(10)
    survivors = load_survivors()
    report: dict[str, object] = {
        "command": "python " + " ".join([f"benchmarks/{Path(sys.argv[0]).name}", *sys.argv[1:]]),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
        "groups": {},
    }
    failed = False
    for name in names:
        group = groups[name]
        args.workdir.mkdir(parents=True, exist_ok=True)
        mode = "report" if args.report else "resume" if args.resume else "fresh"
        result = run_group(group, args.workdir / name, args.jobs, args.workdir / f"{name}.log", mode)
        figures = score(result, survivors)
        print_report(group, figures, args.show, args.skeleton)
        report["groups"][name] = {k: v for k, v in figures.items() if k != "unexplained"} | {
            "unexplained": [[p, k] for p, k, _ in figures["unexplained"]]}
        if args.min_score is not None and figures["total"]["score"] < args.min_score:
            failed = True
        if args.strict and (figures["unexplained"] or figures["stale"]):
            failed = True
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
