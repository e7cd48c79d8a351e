"""experiments/curves_report.py: the fitted change over a curve's last third against a second method, a least-squares
fit with a dummy column per seed and its covariance sigma^2 (X^T X)^-1."""

import json
import os

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _report():
    import curves_report  # experiments/ (pyproject's pythonpath)

    return curves_report


def test_trend_is_the_seed_fixed_effects_least_squares_slope():
    mod = _report()
    steps = np.array([7000.0, 8000.0, 9000.0, 10000.0])
    scores = np.random.default_rng(0).normal(50, 5, (3, 4)) + np.array([[0.0], [20.0], [-10.0]])
    change, se = mod.trend(steps, scores)
    S, E = scores.shape
    X = np.zeros((S * E, S + 1))
    X[np.arange(S * E), np.repeat(np.arange(S), E)] = 1.0
    X[:, S] = np.tile(steps, S)
    coef, res, *_ = np.linalg.lstsq(X, scores.ravel(), rcond=None)
    cov = res[0] / (S * E - S - 1) * np.linalg.inv(X.T @ X)
    np.testing.assert_allclose(change, coef[S] * 3000.0, rtol=1e-9)
    np.testing.assert_allclose(se, np.sqrt(cov[S, S]) * 3000.0, rtol=1e-9)
    # a curve that rises by exactly 6 points over the third, whatever each seed's level: no residual
    change, se = mod.trend(steps, np.array([[0.0], [40.0], [7.0]]) + 2e-3 * (steps - 7000.0))
    np.testing.assert_allclose([change, se], [6.0, 0.0], atol=1e-9)


def test_a_near_zero_slope_through_seeds_that_swing_by_tens_of_points_is_not_flat():
    """BRAC-v at alpha 1.0 over 140k on walker medium (curves.md): per seed over its last third, two seeds jump
    between ~10 and ~90. The fitted change is near 0 and within +-3, but with its SE of ~28 it shows nothing."""
    mod = _report()
    steps = np.array([98000.0, 112000.0, 126000.0, 140000.0])
    swings = np.array([[2.0, 89.9, 19.8, 92.0], [92.0, 89.9, 91.3, 88.1], [86.4, 48.5, 83.1, 10.5]])
    change, se = mod.trend(steps, swings)
    assert abs(change) <= 3 and se > 25
    assert mod.flat_verdict(change, se) == "unresolved"
    assert mod.flat_verdict(-0.5, 4.7) == "yes"  # BC's 50k curve at lr 1e-4
    assert mod.flat_verdict(-22.3, 18.3) == mod.flat_verdict(3.1, 0.0) == "no"
    assert mod.flat_verdict(0.0, float("nan")) == "unresolved"  # one seed, two evaluations: no residual dof


def _curve(method, seeds, means, sha="aa", **config):
    return {"dataset": {"sha256": sha}, "config": dict(method=method, **config), "steps": [1000, 2000],
            "models": [{"method": m, "seed": s, "mean": v} for m in method.split(",") for s, v in zip(seeds, means)]}


def test_pooled_joins_seeds_of_one_setting_only():
    """More seeds of one setting pool across files; a DT's files ignore the critic agents' settings (older files
    saved None for them), a critic agent's do not (BRAC-v at alpha 1 and 3 are two settings), nor other data."""
    mod = _report()
    curves = {"dt-a": _curve("dt", [0, 1], [[10.0, 20.0], [30.0, 40.0]], ac_hidden=None),
              "dt-b": _curve("dt", [3], [[50.0, 60.0]], ac_hidden=256),
              "dt-other-data": _curve("dt", [4], [[0.0, 0.0]], sha="bb"),
              "brac-1": _curve("brac-v", [0], [[1.0, 2.0]], brac_alpha=1.0),
              "brac-1-more": _curve("brac-v", [3], [[3.0, 6.0]], brac_alpha=1.0),
              "brac-3": _curve("brac-v", [5], [[100.0, 100.0]], brac_alpha=3.0)}
    rows = mod.pooled(curves)
    assert {r["pool"] for r in rows} == {"dt-a + dt-b", "brac-1 + brac-1-more"}
    dt = [(r["step"], r["seeds"], r["mean"], r["std"]) for r in rows if r["pool"] == "dt-a + dt-b"]
    np.testing.assert_allclose(dt, [(1000, 3, 30.0, 20.0), (2000, 3, 40.0, 20.0)])
    brac = [(r["step"], r["mean"]) for r in rows if r["method"] == "brac-v"]
    np.testing.assert_allclose(brac, [(1000, 2.0), (2000, 4.0)])


def test_a_tagged_curve_keeps_its_own_file(tmp_path, capsys):
    """``--tag`` (a run on another machine's recording) names its own curve file, so it cannot overwrite this
    machine's curve of the same flags; the flags that name a curve still do. The curve keeps the run's own
    platform record and its training seconds summed over the chunks."""
    import curves as mod  # experiments/ (pyproject's pythonpath)

    flags = ["run", "--env", "walker", "--dataset", "medium", "--model", "paper", "--steps", "10000",
             "--warmup", "500", "--lr-schedule", "cosine", "--ema", "0.999"]
    plain = mod.name_of(mod.build_parser().parse_args(flags))
    assert plain == "walker-medium-paper-k20-cosine-ema0.999-wu500-10000steps"  # a committed curve file
    assert mod.name_of(mod.build_parser().parse_args(flags + ["--tag", "h200"])) == plain + "-h200"
    lr = mod.name_of(mod.build_parser().parse_args(flags + ["--lr", "3e-4"]))  # a rate other than the model's
    assert lr == "walker-medium-paper-k20-cosine-ema0.999-wu500-lr0.0003-10000steps"
    pre = mod.name_of(mod.build_parser().parse_args(flags + ["--pretrain-steps", "2000"]))  # BRAC-v's, BEAR's
    assert pre == "walker-medium-paper-k20-cosine-ema0.999-wu500-pre2000-10000steps"
    assert mod.main(["name"] + flags[1:] + ["--tag", "h200"]) == 0  # what device_curves.sh tars
    assert capsys.readouterr().out == plain + "-h200\n"
    records = [{"step": 10, "loss": 1.0, "chunk_seconds": 2.25}, {"step": 20, "loss": 0.5, "chunk_seconds": 1.5},
               {"step": 20, "eval_episodes": 2, "eval_normalized_score": [40.0], "eval_normalized_score_std": [3.0]}]
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    gpu = {"backend": "gpu", "device": "NVIDIA H200", "devices": 1, "processes": 1, "jax": "0.11.2"}
    res = {"config": {}, "platform": gpu, "models": [{"method": "dt", "seed": 0}],
           "dataset": {"path": "d.hdf5", "sha256": "aa", "episodes": 1, "transitions": 1, "normalized_score_mean": 1.0}}
    curve = mod.collect(str(tmp_path), res)
    assert (curve["platform"], curve["train_seconds"], curve["steps"]) == (gpu, 3.8, [20])
    assert curve["models"] == [{"method": "dt", "seed": 0, "mean": [40.0], "std": [3.0]}]


def test_run_skips_a_finished_curve_and_resumes_a_partial_one(tmp_path, monkeypatch, capsys):
    """A curve whose results file is complete is not trained again (on a fresh machine its run directory is gone);
    a partial one (``snapshot``) is."""
    import curves
    import minsubdt_jax.train

    class Reached(Exception):
        pass

    def train(*a, **k):
        raise Reached

    monkeypatch.setattr(curves, "RESULTS", str(tmp_path))
    monkeypatch.setattr(minsubdt_jax.train, "train", train)
    flags = ["--env", "hopper", "--dataset", "medium-replay", "--model", "cpu", "--steps", "10000", "--tag", "t"]
    path = tmp_path / (curves.name_of(curves.build_parser().parse_args(["run", *flags])) + ".json")
    path.write_text(json.dumps({"models": [], "steps": [1000]}))
    curves.main(["run", *flags])
    assert "complete" in capsys.readouterr().out
    path.write_text(json.dumps({"models": [], "steps": [1000], "partial": True}))
    try:
        curves.main(["run", *flags])
        raise AssertionError("a partial curve was not resumed")
    except Reached:
        pass


def test_bad_input_is_one_error_line(capsys):
    """A bad setting is one line (not a traceback), and is checked before a finished curve is skipped."""
    import curves

    flags = ["--env", "hopper", "--dataset", "medium-replay", "--model", "cpu", "--steps", "10000", "--tag", "rev2",
             "--lr-schedule", "cosine", "--ema", "0.999", "--lr", "1e-3", "--eval-every", "1000", "--episodes", "30"]
    for bad, says in ((["--env", "nope"], "--env must be one of"), (["--seeds", "0"], "--seeds must be > 0")):
        try:
            curves.main(["run", *flags, *bad])
            raise AssertionError(f"{bad} ran")
        except SystemExit as e:
            err = capsys.readouterr().err
            assert e.code == 2 and says in err and "Traceback" not in err, err
