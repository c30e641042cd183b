"""``dyndlo-vision gate RUN --length L --out POLICY.zip``: a distill line run's student with a correction
gate.

The student of a ``distill --teacher-commit K --search-candidates line:N`` run learns its expert's late
correction by least squares and makes about a sixth of it where its observation leaves it unsure whether the
cable needs one (docs/RESULTS.md, session 30). The gate decides that question apart: a logistic classifier
on the student's input at decision K, fitted on the run's rounds, adds the correction ``L`` along the line
whole when its probability reaches ``--threshold``. Writes ``POLICY.zip`` (the student) and ``POLICY.json``
(its metadata with the gate), both atomically; loads by path like any policy (``demo --policy POLICY.zip``).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
from pathlib import Path

HELP = ("fit a correction gate to a distill line run (--search-candidates line:N): its student, correcting "
        "whole")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``gate``."""
    p.add_argument("run_dir", metavar="RUN",
                   help="folder of a finished distill run with --search-candidates line:N")
    p.add_argument("--length", type=float, required=True,
                   help="the correction's length along the run's line (normalised action units, signed)")
    p.add_argument("--threshold", type=float, default=0.5, help="gate probability from which to correct")
    p.add_argument("--l2", type=float, default=1.0, help="the classifier's L2 penalty (standardised inputs)")
    p.add_argument("--model", default=None, metavar="FILE.zip",
                   help="the student to gate (default: RUN/model.zip, the run's last)")
    p.add_argument("--out", required=True, metavar="POLICY.zip", help="the gated policy (and POLICY.json)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing POLICY.zip / .json")


def run(args: argparse.Namespace) -> int:
    """Fit the gate, report how it does on held-out rounds, write the policy."""
    import numpy as np

    from dyndlo_vision import policies
    from dyndlo_vision._atomic import write_atomic
    from dyndlo_vision.learning.correction_gate import (
        fit_gate,
        gate_examples,
        held_out_probabilities,
        rank_auc,
    )

    run_dir, out = Path(args.run_dir), Path(args.out)
    if out.suffix != ".zip":
        raise ValueError(f"--out {out}: expected a .zip path (its metadata goes to the .json beside it)")
    if not math.isfinite(args.length) or args.length == 0:
        raise ValueError(f"--length {args.length!r}: expected a finite, non-zero length")
    if not 0 < args.threshold < 1:
        raise ValueError(f"--threshold {args.threshold!r}: expected a probability in (0, 1)")
    if not (args.l2 > 0 and math.isfinite(args.l2)):
        raise ValueError(f"--l2 {args.l2!r}: expected a positive number")
    model = Path(args.model) if args.model else run_dir / "model.zip"
    meta_in = model.with_suffix(".json")
    for path in (model, meta_in):
        if not path.is_file():
            raise FileNotFoundError(f"{path} does not exist: RUN must be a finished distill run")
    meta = json.loads(meta_in.read_text())
    existing = [str(p) for p in (out, out.with_suffix(".json")) if p.exists()]
    if existing and not args.overwrite:
        raise FileExistsError(f"{', '.join(existing)} exist; pass --overwrite to replace them")

    examples = gate_examples(run_dir)
    gate = fit_gate(run_dir, args.length, args.threshold, args.l2, examples)
    # A student that does not load, or whose input the gate does not fit: refused before anything is written.
    student = policies.load(model)
    history, clock = int(meta.get("p_dlo_history") or 0), bool(meta.get("decision_clock"))
    if not (history or clock):
        raise ValueError(f"{model}: a gate needs a student with p_dlo_history or decision_clock")
    policies.GatedPolicy(getattr(student, "sb3_model", student), gate, history, clock)
    y = examples["corrected"]
    held = held_out_probabilities(examples, args.l2) if len(np.unique(examples["rounds"])) > 1 else None
    gated = np.array([gate.probability(x) >= gate.threshold for x in examples["inputs"]], dtype=bool)
    report = {
        "examples": int(len(y)),
        "corrected": int(y.sum()),
        "fitted_gated": {"corrected": int((gated & y).sum()), "uncorrected": int((gated & ~y).sum())},
    }
    if held is not None:
        report["held_out"] = {"auc": round(rank_auc(held, y), 3),
                              "gated_corrected": int(((held >= gate.threshold) & y).sum()),
                              "gated_uncorrected": int(((held >= gate.threshold) & ~y).sum())}
    meta = {**meta, "correction_gate": gate.to_json(),
            "correction_gate_fit": {"run": str(run_dir), "model": str(model), "l2": args.l2, **report}}
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, lambda tmp: shutil.copyfile(model, tmp))
    write_atomic(out.with_suffix(".json"), lambda tmp: Path(tmp).write_text(json.dumps(meta, indent=2)))
    policies.load(out)  # what was written loads as a gated policy
    print(json.dumps(report))
    return 0
