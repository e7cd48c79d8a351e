"""experiments/front.py's bookkeeping: a cell whose results file is complete is not trained again (on a fresh
machine its run directories are gone, and ``run`` would retrain ~3 h of models to recompute what is committed); and
the lines of experiments/front_report.py, against hand computations."""

import json
import shutil

import numpy as np
import pytest


@pytest.fixture()
def front(tmp_path, monkeypatch):
    import front  # experiments/ (pyproject's pythonpath)

    monkeypatch.setattr(front, "RESULTS", str(tmp_path))
    return front


@pytest.fixture
def front_report():
    import front_report  # experiments/ (pyproject's pythonpath)
    return front_report


def cell_file(front, tmp_path, drop_target=False, drop_scalar=False):
    """A results file of walker medium-replay with every target of a 2 x 2 grid and every scalar run, its vector
    models trained on a recording hashed "aa" x 32."""
    demo = np.array([[0.2, 0.9], [0.8, 0.1], [0.5, 0.5]])
    sweeps = {m: [{"target": t, "normalized": [1.0], "costs": [[0.5, 0.5]]}
                  for t in front.grid_targets(m, demo, 1.0, 2)] for m in front.VECTOR}
    if drop_target:
        sweeps["dt-vec"].pop()
    scalar = {n: {"normalized": [1.0], "costs": [[0.5, 0.5]]} for n in front.RUNS if n != "vec"}
    if drop_scalar:
        scalar.popitem()
    out = {"cell": "walker-medium-replay", "preset": "study", "seeds": 3, "episodes": 100, "beta": 1.0,
           "dataset_sha256": "aa" * 32, "demo_costs": demo.tolist(), "sweeps": sweeps, "scalar": scalar}
    (tmp_path / "walker-medium-replay.json").write_text(json.dumps(out))


ARGS = ["run", "--env", "walker", "--dataset", "medium-replay", "--grid", "2"]


class Reached(Exception):
    """train_runs was called: the cell would train."""


def reach(*a, **k):
    raise Reached


def test_a_complete_cell_is_not_trained_again(front, tmp_path, monkeypatch, capsys):
    cell_file(front, tmp_path)
    monkeypatch.setattr(front, "train_runs", reach)
    front.main(ARGS)
    assert "complete" in capsys.readouterr().out
    with pytest.raises(Reached):  # another grid is other work (for the vector models that swept the file's)
        front.main(ARGS[:-1] + ["3"] + vector_run(tmp_path))


def vector_run(tmp_path, sha="aa" * 32):
    """``--runs-root`` whose walker medium-replay vector run has finished, trained on a recording hashed ``sha``."""
    vec = tmp_path / "runs" / "walker-medium-replay" / "vec"
    vec.mkdir(parents=True)
    (vec / "results.json").write_text(json.dumps({"dataset": {"sha256": sha}}))
    return ["--runs-root", str(tmp_path / "runs")]


@pytest.mark.parametrize("gap", ["drop_target", "drop_scalar"])
def test_an_incomplete_cell_trains(front, tmp_path, monkeypatch, gap):
    cell_file(front, tmp_path, **{gap: True})
    monkeypatch.setattr(front, "train_runs", reach)
    with pytest.raises(Reached):
        front.main(ARGS + vector_run(tmp_path))


@pytest.mark.parametrize("sha", [None, "cc" * 32])
def test_a_part_swept_cell_does_not_mix_in_other_vector_models(front, tmp_path, monkeypatch, capsys, sha):
    """Targets are saved as they are rolled out, and the file is committed once both sweeps are done; a part-swept
    file on a machine without its vector run (gone, or trained again on another recording) must not be finished
    with new models: one front would hold the targets of two trainings. One error line; nothing trains or changes."""
    cell_file(front, tmp_path, drop_target=True)
    path = tmp_path / "walker-medium-replay.json"
    before = path.read_text()
    monkeypatch.setattr(front, "train_runs", reach)
    with pytest.raises(SystemExit) as e:
        front.main(ARGS + (vector_run(tmp_path, sha) if sha else ["--runs-root", str(tmp_path / "runs")]))
    err = capsys.readouterr().err
    assert e.value.code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 2, err  # usage + error
    assert "7 targets" in err and ("cccccccccccc" in err if sha else "does not hold" in err)
    assert path.read_text() == before


def scalar_trainer(tmp_path, trained):
    """A fake ``train_runs`` for scalar runs: records the names asked for in ``trained`` and writes each run's
    ``results.json`` (3 seeds at normalised 7.0, costs 0.25 and 0.75, a recording hashed "bb" x 32)."""
    def train_runs(a, names):
        trained.extend(names)
        out = tmp_path / "runs" / names[0]
        out.mkdir(parents=True)
        (out / "results.json").write_text(json.dumps({"dataset": {"sha256": "bb" * 32}, "eval_per_seed": [
            {"normalized_score_mean": 7.0, "costs_mean": {"x_velocity": 0.25, "energy@lived": 0.75}}] * 3}))
        return {names[0]: str(out)}

    return train_runs


def test_a_cell_with_every_target_trains_only_its_missing_scalar_run(front, tmp_path, monkeypatch):
    """On a fresh machine the vector run's directory is gone; a cell whose sweeps are all in its file must not train
    the vector methods again (hours) to reach the scalar run it lacks: only that run trains, and it lands in the file
    beside the sweeps, which stay as they were."""
    cell_file(front, tmp_path, drop_scalar=True)
    path = tmp_path / "walker-medium-replay.json"
    before = json.loads(path.read_text())
    trained = []
    monkeypatch.setattr(front, "train_runs", scalar_trainer(tmp_path, trained))
    front.main(ARGS)
    after = json.loads(path.read_text())
    assert trained == ["minsubdt-both"]
    assert after["sweeps"] == before["sweeps"] and after["demo_costs"] == before["demo_costs"]
    assert after["scalar"]["minsubdt-both"] == {"normalized": [7.0] * 3, "costs": [[0.25, 0.75]] * 3,
                                                "dataset_sha256": "bb" * 32}


def test_commit_lands_the_cell_file_after_each_scalar_run(front, tmp_path, monkeypatch, git_repo):
    """``run --commit``: a machine can vanish mid-cell (its run directories with it), so each scalar run's result is
    committed as it lands, the cell file alone (other changes in the work tree stay as they are)."""
    cell_file(front, tmp_path, drop_scalar=True)
    (tmp_path / "other.txt").write_text("work in progress")
    monkeypatch.setattr(front, "train_runs", scalar_trainer(tmp_path, []))
    front.main([*ARGS, "--commit"])
    assert git_repo("log", "-1", "--format=%s").strip() == ("Front (issue 55), walker-medium-replay: minsubdt-both "
                                                       "landed; resume: bash experiments/queue.sh front")
    assert git_repo("show", "--name-only", "--format=").split() == ["walker-medium-replay.json"]
    assert "other.txt" in git_repo("status", "--porcelain")


def test_the_scalar_runs_min_subdominance_is_a_hand_computation(front_report):
    """Eq. 2 against one demo at (0.5, 0.5), beta 1: a point better in speed and worse in energy pays beta in energy
    alone (alpha 0 there, alpha -> inf on speed): 1; one worse in both pays 2; one better in both 0. The demos' own
    value holds each against the others (two demos, each better than the other in one metric: 1 each)."""
    r = {"beta": 1.0, "demo_costs": [[0.5, 0.5]], "scalar": {
        "a": {"costs": [[0.2, 0.9], [0.2, 0.9]]}, "b": {"costs": [[0.6, 0.6]]}, "c": {"costs": [[0.1, 0.1]]}}}
    assert front_report.scalar_subdominance(r) == (
        "Eq. 2 against the demos in these two costs (beta 1.0; lower: fewer demos beat it): `a` 1.000 (costs 0.200, "
        "0.900), `b` 2.000 (costs 0.600, 0.600), `c` 0.000 (costs 0.100, 0.100).")  # one demo: none to hold it against
    r["demo_costs"] = [[0.2, 0.9], [0.9, 0.2]]
    assert "the demos' own, each against the others, 1.000-1.000 (median 1.000)" in front_report.scalar_subdominance(r)


def test_scalar_runs_on_another_recording_are_named(front_report):
    """A scalar run whose recording's hash is not the sweeps' is named with its hash; one without a hash (recorded
    before the field) or with the sweeps' is not."""
    r = {"dataset_sha256": "aa" * 32, "scalar": {"x": {"dataset_sha256": "aa" * 32}, "y": {},
                                                  "z": {"dataset_sha256": "cc" * 32}}}
    assert front_report.recordings(r) == ("Trained on another recording of the same recipe (the target sweeps': "
                                          "aaaaaaaaaaaa): `z` (cccccccccccc).")
    del r["scalar"]["z"]
    assert front_report.recordings(r) == ""


@pytest.mark.parametrize("flags,says", [
    (["--env", "nope"], "--env must be one of"), (["--preset", "nope"], "--preset must be one of"),
    (["--dataset", "nope"], "--dataset must be one of"),
    (["--grid", "1"], "--grid must be >= 2"), (["--seeds", "0"], "--seeds must be > 0"),
    (["--episodes", "0"], "--episodes must be > 0"), (["--steps", "0"], "--steps must be > 0")])
def test_bad_input_is_one_error_line_and_changes_nothing(front, tmp_path, monkeypatch, capsys, flags, says):
    cell_file(front, tmp_path)
    before = (tmp_path / "walker-medium-replay.json").read_text()
    monkeypatch.setattr(front, "train_runs", reach)
    with pytest.raises(SystemExit) as e:
        front.main(["run", "--env", "walker", "--dataset", "medium-replay", "--grid", "2", *flags])
    err = capsys.readouterr().err
    assert e.value.code == 2 and says in err and "Traceback" not in err, err
    assert (tmp_path / "walker-medium-replay.json").read_text() == before


def test_other_settings_on_a_cell_with_results_are_an_error_not_a_rewrite(front, tmp_path, monkeypatch, capsys):
    """The cell's file was made with 3 seeds x 100 episodes: a run with 2 seeds would have rewritten its settings
    beside targets measured with 3 (it did, before this test). Another --tag keeps them apart."""
    cell_file(front, tmp_path, drop_target=True)
    before = (tmp_path / "walker-medium-replay.json").read_text()
    monkeypatch.setattr(front, "train_runs", reach)
    with pytest.raises(SystemExit) as e:
        front.main([*ARGS, "--seeds", "2"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "--seeds 3" in err and "--tag" in err
    assert (tmp_path / "walker-medium-replay.json").read_text() == before


def test_steering_with_the_other_target_held_reads_each_row_of_the_grid(front_report):
    """Metric 0's cost follows its target where the other target is 0.5 or 1 and runs against it where that is 0:
    by hand, the rows' Spearman are -1, +1, +1, so the held measure is 1/3, while metric 1 (cost = its target)
    is +1; a seed axis of two identical seeds changes nothing."""
    t = np.array([[a, b] for a in (0.0, 0.5, 1.0) for b in (0.0, 0.5, 1.0)])
    c0 = np.where(t[:, 1] == 0.0, 0.9 - 0.1 * t[:, 0], t[:, 0])
    c = np.stack([c0, t[:, 1] + 0.01 * t[:, 0]], -1)[:, None].repeat(2, 1)  # [9, 2 seeds, 2]
    assert front_report.steering(t, c, 0, held=True) == pytest.approx(1 / 3)
    assert front_report.steering(t, c, 1, held=True) == pytest.approx(1.0)


def test_the_demos_trade_off_line_is_a_hand_computation(front_report):
    """20 demos: energy cost i / 20, speed cost 1 - i / 20 but demos 0 and 10 swapped, so the ranks are the reversal
    with two of them 10 apart: Spearman -(1 - 6 * 200 / (20 * 399)) = -0.85; the least-energy tenth is demos 0 and
    1, at energy 0.025 and speed (0.5 + 0.95) / 2."""
    energy = np.arange(20) / 20.0
    speed = 1.0 - energy
    speed[[0, 10]] = speed[[10, 0]]
    line = front_report.demos_trade_off(np.stack([speed, energy], 1))
    assert "Spearman -0.85" in line and "energy@lived cost 0.025" in line and "x_velocity cost 0.725" in line
    assert "(all demos 0.050-1.000)" in line


def test_targets_beyond_the_demos_are_counted_by_hand(front_report):
    """Demos spend energy 0.3-0.6 and speed 0.5-0.9; of three target means one spends less energy than any demo
    and one is faster than any: each is named with its cost in the other metric."""
    demos = np.array([[0.9, 0.3], [0.5, 0.6]])
    means = np.array([[0.95, 0.01], [0.4, 0.7], [0.7, 0.5]])
    line = front_report.beyond_demos("m", means, demos)
    assert line == ("`m`: 1 of 3 targets below every demo's x_velocity cost (0.500; theirs 0.400, at energy@lived "
                    "cost 0.700); 1 of 3 targets below every demo's energy@lived cost (0.300; theirs 0.010, at "
                    "x_velocity cost 0.950).")
    assert front_report.beyond_demos("m", means[2:], demos) == ""


def test_a_cell_file_says_whether_it_is_partial_as_each_part_lands(front, tmp_path, monkeypatch):
    """The file is saved as each target and scalar run lands, and a machine may stop between two: the file itself
    says whether it holds all the cell's work (the report shows no numbers of a partial one)."""
    cell_file(front, tmp_path, drop_scalar=True)
    path = tmp_path / "walker-medium-replay.json"
    seen = []  # the flag of each save, read back from the file
    import minsubdt_jax.atomic as atomic
    real = atomic.write_atomic
    monkeypatch.setattr(atomic, "write_atomic", lambda p, text: (real(p, text), seen.append(
        json.loads(path.read_text()).get("partial"))))
    monkeypatch.setattr(front, "train_runs", scalar_trainer(tmp_path, []))
    front.main(ARGS)
    assert seen == [False]
    data = json.loads(path.read_text())
    del data["scalar"]["minsubdt-both"], data["scalar"]["minsubdt-x_velocity"]
    path.write_text(json.dumps(data))
    seen.clear()
    shutil.rmtree(tmp_path / "runs")  # the fake trainer makes each run's directory anew
    front.main(ARGS)
    assert seen == [True, False]  # one scalar run landed of two, then the other


def test_the_report_shows_no_numbers_of_a_partial_cell(front, front_report, tmp_path, monkeypatch):
    """A cell under way (its file ``partial``: a sweep or a scalar run missing) is one line saying what it holds;
    its hypervolumes and Spearman would be read as results (a 3-target sweep gave Spearman nan). Complete cells,
    and files from before the flag, are reported as before; only they are drawn."""
    cell_file(front, tmp_path)
    done = {**json.loads((tmp_path / "walker-medium-replay.json").read_text()), "seeds": 1, "command": "c"}
    for sweep in done["sweeps"].values():  # costs that follow the targets: a Spearman of +1, not nan
        for s in sweep:
            s["costs"] = [[s["target"]["x_velocity"] / 2, s["target"]["energy@lived"] / 2]]
    (tmp_path / "walker-medium-replay.json").write_text(json.dumps(done))
    part = {**done, "cell": "walker-medium", "partial": True, "scalar": {},
            "sweeps": {"minsubdt-vec": done["sweeps"]["minsubdt-vec"], "dt-vec": done["sweeps"]["dt-vec"][:1]}}
    (tmp_path / "walker-medium.json").write_text(json.dumps(part))
    (tmp_path / "results").mkdir()
    monkeypatch.setattr(front_report, "RESULTS", str(tmp_path))
    monkeypatch.setattr(front_report, "HERE", str(tmp_path))
    monkeypatch.setattr(front_report, "hypervolume", lambda p: 0.5)  # moocore is the optional [front] extra
    front_report.report(None)
    md = (tmp_path / "results" / "front.md").read_text()
    assert "### walker-medium-replay" in md and "### walker-medium " not in md and "nan" not in md
    assert ("walker-medium: under way, not a result yet (minsubdt-vec 4 targets, dt-vec 1, scalar runs none); "
            "`bash experiments/queue.sh front` resumes it") in md
    assert (tmp_path / "results" / "front.png").exists()


def test_the_points_reach_is_min_max_by_hand(front_report):
    """Three demos (speed 0.5-0.9, energy 0.3-0.6; medians 0.7, 0.5) and two target means: each set's range per
    metric, as read off the arrays."""
    pts = {"demos": np.array([[0.9, 0.3], [0.5, 0.6], [0.7, 0.5]]), "m": np.array([[0.95, 0.01], [0.4, 0.7]])}
    assert front_report.reach(pts) == (
        "Costs reached, min-max over the points (x_velocity, energy@lived): demos 0.500-0.900, 0.300-0.600; "
        "m 0.400-0.950, 0.010-0.700; the demos' medians 0.700, 0.500.")
