"""Render the table of docs/steering.md, "Why Stack D1 falls as training starts", from the files
run.sh wrote beside this script (evals.jsonl, probe-8k/ and probe-32k/critic-probe.json) and the
study run's train.csv: ``python docs/steering/study/stack-collapse/table.py`` writes table.md."""

import csv
import json
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _rate(e: dict) -> str:
    lo, hi = e["wilson95"]
    return f"{e['rate']:.3f} [{lo:.3f}, {hi:.3f}]"


def _ms(m: dict, sign: bool = True) -> str:
    return f"{m['mean']:+.3f} +- {m['se']:.3f}" if sign else f"{m['mean']:.3f} +- {m['se']:.3f}"


def main() -> None:
    ev = {(e["at"], e["arm"]): e for e in map(json.loads, (HERE / "evals.jsonl").read_text().splitlines())}
    pr = {k: json.loads((HERE / f"probe-{k // 1000}k" / "critic-probe.json").read_text()) for k in (8000, 32000)}
    # the learner's record: the 8k rerun's, and the study run's own for 32k
    study_run = HERE.parent / "runs" / "stack" / "stack" / "equi" / "seed0" / "train.csv"
    kl = {int(r["env_steps"]): float(r["prior_kl"]) for r in csv.DictReader(open(study_run))}
    at = (0, 8000, 32000)
    cell = lambda k, arm, f: f(ev[(k, arm)]) if (k, arm) in ev else ""  # noqa: E731
    rows = [
        ("the actor's samples (what the evaluations measure)", [cell(k, "sampled", _rate) for k in at]),
        ("the critic's best of 16 fresh N(0, I) noises at every chunk", [cell(k, "best-of-16", _rate) for k in at]),
        ("the actor's mean at every chunk", [cell(k, "mean", _rate) for k in at]),
        (
            "norm of the mean picked noise (actor's samples / best of 16)",
            [
                f"{ev[(k, 'sampled')]['noise_mean_norm']:.2f} / {ev[(k, 'best-of-16')]['noise_mean_norm']:.2f}"
                for k in at
            ],
        ),
        ("the actor's KL to N(0, I), nats (`train.csv`)", [f"{kl[k if k else 16]:.1f}" for k in at]),
        (
            "probe: Spearman(Q, MC success) over one chunk's 6 noises",
            [_ms(pr[8000]["rho_success_untrained"])] + [_ms(pr[k]["rho_success"]) for k in (8000, 32000)],
        ),
        (
            "probe: the critic's pick among them, MC success minus the state's mean",
            [_ms(pr[8000]["critic_pick_gain_untrained"])] + [_ms(pr[k]["critic_pick_gain"]) for k in (8000, 32000)],
        ),
        (
            "probe: as a value across states, correlation / slope of Q on the MC return",
            [""] + [f"{pr[k]['values']['correlation']:+.2f} / {pr[k]['values']['slope']:.3f}" for k in (8000, 32000)],
        ),
    ]
    out = [
        "| Stack D1, Equi-DSRL seed 0, 200 pinned starts | untrained learner (the base) | at 8k env steps | at 32k |"
    ]
    out.append("|---|---:|---:|---:|")
    out += [f"| {name} | " + " | ".join(cells) + " |" for name, cells in rows]
    (HERE / "table.md").write_text("\n".join(out) + "\n")
    print("\n".join(out))


if __name__ == "__main__":
    main()
