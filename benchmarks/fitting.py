"""Fitting: `rig fit`, `rig fit --model` and `rig diagnose` on the sweep against the paper's likelihood in a short
script; the fit against the per-sample MLE over raw samples; the fit's time against pixel-stops."""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

from .baselines import PAPER_SCRIPT, per_sample_mle
from .data import RIG
from .figures import Figure, run_measured

THREE_EFFECTS = "active+noise_floor+slant_range+outliers"
#: s of CPU the paper's script took on the sweep on the machine issue 30's targets were stated on (the full run of
#: 2026-11-25 at e280f1d): a target of T s there is T / 1.10 times the script in the same run here
ISSUE_30_SCRIPT_S = 1.10


def issue_30_target(target_s: float, ours_s: float, script_s: float) -> tuple[str, bool]:
    """Issue 30's target of `target_s` seconds, in the words of the table and met or not: `ours_s` against the paper's
    script on the sweep in the same run (`script_s`), as the issue's seconds scale to this machine."""
    limit = target_s / ISSUE_30_SCRIPT_S
    return f"< {target_s:g} s (issue 30; the script {ISSUE_30_SCRIPT_S:.2f} s): < {limit:.2f}x", ours_s / script_s < limit


def commands(sweep: Path, workdir: Path) -> list[Figure]:
    """`rig fit`, `rig fit --model` (three effects) and `rig diagnose` on the sweep, CPU s (and peak memory for
    `rig fit`), each against the paper's script on the same file."""
    script = workdir / "paper_fit.py"
    script.write_text(PAPER_SCRIPT)
    base_cpu, base_mb, _, base_out = run_measured([sys.executable, str(script), str(sweep)])
    k_script, lam_script = (float(x) for x in base_out.split()[:2])
    fit_cpu, fit_mb, fit_wall, fit_out = run_measured([RIG, "-q", "fit", str(sweep), "--json"])
    doc = json.loads(fit_out[fit_out.index("{"):])
    fit = doc["fits"][0]
    k, lam = fit["values"]["k"], fit["values"]["lambda"]
    agree = max(abs(k / k_script - 1), abs(lam / lam_script - 1))
    out = [
        Figure("rig fit (power law) on the sweep, CPU", fit_cpu, base_cpu, "s", *issue_30_target(2.0, fit_cpu, base_cpu),
               "the paper's likelihood in a 30-line script", note=f"wall {fit_wall:.1f} s; k and lambda agree to {agree:.1e}",
               extra={"k": k, "lambda": lam, "k_script": k_script, "lambda_script": lam_script}),
        Figure("rig fit (power law) on the sweep, peak memory", fit_mb, base_mb, "MB", "< 500 MB", fit_mb < 500.0,
               "the same script"),
    ]
    model_cpu, _, model_wall, _ = run_measured([RIG, "-q", "fit", str(sweep), "--model", THREE_EFFECTS, "--no-held-out"])
    out.append(Figure(f"rig fit --model {THREE_EFFECTS} --no-held-out on the sweep, CPU", model_cpu, base_cpu, "s",
                      *issue_30_target(10.0, model_cpu, base_cpu), "the paper's script", note=f"wall {model_wall:.1f} s"))
    # as a user runs it: with the held-out score (eleven refits, one stop left out each, in --jobs processes)
    held_cpu, held_mb, held_wall, _ = run_measured([RIG, "-q", "fit", str(sweep), "--model", THREE_EFFECTS])
    out.append(Figure(f"rig fit --model {THREE_EFFECTS} on the sweep (with its held-out score), wall", held_wall,
                      base_cpu, "s", "< 10 s", held_wall < 10.0, "the paper's script (CPU)",
                      note=f"CPU {held_cpu:.1f} s over the processes; peak {held_mb:.0f} MB"))
    with tempfile.TemporaryDirectory() as tmp:
        diag_cpu, diag_mb, diag_wall, _ = run_measured([RIG, "-q", "diagnose", str(sweep), "--out", tmp])
    out.append(Figure("rig diagnose (every candidate) on the sweep, CPU over its processes", diag_cpu, base_cpu, "s",
                      *issue_30_target(15.0, diag_cpu, base_cpu), "the paper's script",
                      note=f"wall {diag_wall:.1f} s (--jobs: one per core); peak {diag_mb:.0f} MB"))
    return out


def blind_table(demo: Path, workdir: Path, seeds: int) -> list[Figure]:
    """`rig validate-diagnosis` (every scenario of docs/models.md's blind table, `seeds` seeds each, a process a core),
    wall minutes, against the paper's script on a recording of a trial's size (the demo's) times the trials, over
    the cores: what the same trials would cost if each were only the paper's fit."""
    import json
    import os

    script = workdir / "paper_fit.py"
    script.write_text(PAPER_SCRIPT)
    base_cpu, _, _, _ = run_measured([sys.executable, str(script), str(demo)])
    trials_json = workdir / "blind-table-trials.json"
    cores = os.cpu_count() or 1
    cpu, _, wall, _ = run_measured([RIG, "-q", "validate-diagnosis", "--seeds", str(seeds), "--first-seed", "1000",
                                    "--json", str(trials_json)])
    trials = json.loads(trials_json.read_text())
    within = sum(t["within_noise"] for t in trials)
    rows: dict[str, list[bool]] = {}
    for t in trials:
        rows.setdefault(t["effect"], []).append(t["within_noise"])
    short = sorted(f"{k} {sum(v)}/{len(v)}" for k, v in rows.items() if sum(v) < 0.9 * len(v))
    return [Figure(f"the blind table ({len(trials)} trials: {len(rows)} scenarios x {seeds} seeds), wall", wall / 60,
                   base_cpu * len(trials) / cores / 60, "min", "< 15 min on 2 cores (issue 30)", wall / 60 < 15.0,
                   f"the paper's script on a trial-sized recording, x {len(trials)} trials / {cores} cores",
                   note=f"CPU {cpu / 60:.1f} min; {within}/{len(trials)} within noise"
                        + (f"; rows under 9/10: {', '.join(short)}" if short else ""),
                   extra={"within_noise": within, "trials": len(trials), "rows": {k: sum(v) for k, v in rows.items()}})]


def small(demo: Path, workdir: Path, sweep: Path | None = None) -> list[Figure]:
    """What the operator waits for on the demo's 106x60 recording (issue 30's targets, CPU s): `rig diagnose`
    (one process, as the demo runs it) and `rig fit --model` with an empirical term as a user runs it (with its
    held-out score). Against the paper's script on the sweep when there is one (`sweep`), to which issue 30's
    seconds scale (`issue_30_target`); otherwise against the script on the demo, and the targets in plain seconds."""
    script = workdir / "paper_fit.py"
    script.write_text(PAPER_SCRIPT)
    base_cpu, _, _, _ = run_measured([sys.executable, str(script), str(sweep or demo)])
    base_name = "the paper's script on the sweep" if sweep else "the paper's script on it"

    def target(ours: float) -> tuple[str, bool]:
        return issue_30_target(5.0, ours, base_cpu) if sweep else ("< 5 s", ours < 5.0)

    out = []
    with tempfile.TemporaryDirectory() as tmp:
        diag_cpu, diag_mb, diag_wall, _ = run_measured([RIG, "-q", "diagnose", str(demo), "--jobs", "1", "--out", tmp])
    out.append(Figure("rig diagnose on the demo's 106x60 recording (--jobs 1), CPU", diag_cpu, base_cpu, "s",
                      *target(diag_cpu), base_name, note=f"wall {diag_wall:.1f} s; peak {diag_mb:.0f} MB"))
    model = "active+noise_floor+empirical(radius)"
    fit_cpu, _, fit_wall, _ = run_measured([RIG, "-q", "fit", str(demo), "--model", model])
    out.append(Figure(f"rig fit --model {model} on the demo's recording (with its held-out score), CPU", fit_cpu,
                      base_cpu, "s", *target(fit_cpu), base_name, note=f"wall {fit_wall:.1f} s, over the processes"))
    return out


def against_per_sample(raw: Path) -> list[Figure]:
    """The fit from per-pixel statistics against the paper's MLE over every raw sample, same recording."""
    from protocols.recording import Recording
    from rig.models import fit_power_law, load_samples

    import h5py

    with Recording(raw) as rec:
        cal, labels = rec.calibration, rec.stop_labels()
    with h5py.File(raw, "r") as f:  # the raw frames, as the baseline would read them
        frames = [f["stops"][label]["raw_depth"][()] for label in labels]
    t0 = time.process_time()
    with Recording(raw) as rec:
        ours = fit_power_law(load_samples(rec))
    t_ours = time.process_time() - t0
    t0 = time.process_time()
    k, lam, samples = per_sample_mle(frames, cal.depth_scale_m)
    t_base = time.process_time() - t0
    agree = max(abs(ours.k / k - 1), abs(ours.lam / lam - 1))
    return [Figure(f"fit from per-pixel statistics against a per-sample scipy MLE ({samples / 1e6:.1f} M samples), CPU",
                   t_ours, t_base, "s", "the same k and lambda to 1e-6", agree < 1e-6, "per-sample MLE over raw frames",
                   note=f"k and lambda agree to {agree:.1e}",
                   extra={"k": ours.k, "lambda": ours.lam, "k_per_sample": k, "lambda_per_sample": lam})]


def scaling(sweep: Path) -> list[Figure]:
    """The power-law fit's CPU time against pixel-stops: every 8th, 4th, 2nd and every pixel of the sweep."""
    from protocols.recording import Recording
    from rig.models import ModelData, fit_power_law, load_samples

    with Recording(sweep) as rec:
        d = load_samples(rec)
    fit_power_law(d.select(slice(0, 1000)))  # compiled before timing
    rows = []
    for step in (8, 4, 2, 1):
        part = d if step == 1 else ModelData(z_m=d.z_m[::step].copy(), m2_m2=d.m2_m2[::step].copy(),
                                             m4_m4=d.m4_m4[::step].copy(), n=d.n[::step].copy(), stop=d.stop[::step].copy())
        best = min(_timed(lambda: fit_power_law(part)) for _ in range(3))
        rows.append((len(part), best))
    per = [t / n for n, t in rows]
    linear = max(per) / min(per)
    return [Figure(f"fit time per pixel-stop at {n / 1e6:.2f} M pixel-stops", 1e9 * t / n, 1e9 * rows[0][1] / rows[0][0],
                   "ns", "grows linearly: within 2x of the smallest size's", linear < 2.0, "the smallest size",
                   note=f"{t:.3f} s in all") for n, t in rows]


def _timed(fn) -> float:
    t0 = time.process_time()
    fn()
    return time.process_time() - t0
