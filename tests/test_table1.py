"""experiments/table1.py: grouping the missing runs into programs, skipping finished runs, splitting a program's
models into one result file each, and aggregating partial results (a fake trainer; the report's lines are
tests/test_table1_report.py's)."""

import dataclasses
import json
import os
import threading

import numpy as np
import pytest

import gitcommit  # experiments/ (pyproject's pythonpath)
import table1_units
from minsubdt_jax.agents import AGENTS, preset_config
from minsubdt_jax.config import PRESETS
from minsubdt_jax.rundir import Interrupted
from minsubdt_jax.agents.dt.networks import DT_REVISION
from table1_fakes import BASE, fake_results, recording_sweep


def test_whole_env_sweep_trains_the_env_in_one_program(table1, tmp_path):
    """--whole-env: an env's datasets missing the same seeds of the same methods are one program (--dataset a,b);
    each model's file names its own dataset and holds its own evaluation."""
    calls = []

    def fake_train(cfg, resume=False, verbose=False):
        calls.append((cfg.env, cfg.dataset, cfg.method, cfg.seed, cfg.seeds, os.path.basename(cfg.out),
                      cfg.precision))
        return fake_results(cfg)

    kw = dict(preset="smoke", envs=("hopper", "walker"), datasets=("medium", "medium-replay"),
              runs_root=str(tmp_path / "runs"), results_root=str(tmp_path / "res"), train_fn=fake_train,
              log=lambda *_: None, whole_env=True, precision="bf16")
    res_dir = tmp_path / "res" / "table1" / "smoke"
    res_dir.mkdir(parents=True)
    done = dataclasses.replace(preset_config("smoke", "dt"), precision="bf16")  # walker medium has DT's seed 0
    (res_dir / "walker-medium-dt-s0.json").write_text(json.dumps({"config": dataclasses.asdict(done),
                                                                      "dt_revision": DT_REVISION}))
    st = table1.run_sweep(methods=("minsubdt", "dt"), seeds=(0, 1), **kw)
    assert calls == [
        ("hopper", "medium,medium-replay", "minsubdt,dt", 0, 2, "hopper-medium+medium-replay-minsubdt+dt-s0-1", "bf16"),
        ("walker", "medium", "minsubdt", 0, 2, "walker-medium-minsubdt-s0-1", "bf16"),
        ("walker", "medium-replay", "minsubdt,dt", 0, 2, "walker-medium-replay-minsubdt+dt-s0-1", "bf16"),
        ("walker", "medium", "dt", 1, 1, "walker-medium-dt-s1", "bf16")]
    assert st["skipped"] == ["walker-medium-dt-s0"] and not st["failed"] and len(st["done"]) == 15
    calls.clear()  # the critic agents' units are the same, AWR's one per dataset (its step reads every episode)
    table1.run_sweep(methods=("iql", "awr"), seeds=(0,), **dict(kw, envs=("hopper",)))
    assert [c[:3] for c in calls] == [("hopper", "medium,medium-replay", "iql"), ("hopper", "medium", "awr"),
                                      ("hopper", "medium-replay", "awr")]
    assert {c[-1] for c in calls} == {"bf16"}  # --precision is every agent's (issue 58)
    r = json.loads((res_dir / "hopper-medium-replay-dt-s1.json").read_text())
    assert r["config"]["dataset"] == "medium-replay" and r["config"]["method"] == "dt" and r["config"]["seed"] == 1
    assert r["eval"]["normalized_score_mean"] == BASE["dt"] + 1 + 100  # the second dataset's model


def test_commit_results_commits_only_the_unit_files_and_waits_out_another_commit(tmp_path, git_repo):
    """The sweep commits beside a developer's commits: a unit landing while another git process holds the index lock
    waits for it (here 1 s) instead of dying with its results uncommitted."""
    git = git_repo
    git("commit", "-q", "--allow-empty", "-m", "root")
    (tmp_path / "res").mkdir()
    (tmp_path / "res" / "a.json").write_text("{}")
    (tmp_path / "other.txt").write_text("work in progress")
    (tmp_path / ".git" / "index.lock").write_text("")
    threading.Timer(1.0, (tmp_path / ".git" / "index.lock").unlink).start()
    assert gitcommit.commit_results([str(tmp_path / "res" / "a.json")], "Table 1 (smoke): x; resume: python ...")
    assert git("log", "-1", "--format=%s").strip() == "Table 1 (smoke): x; resume: python ..."
    assert git("show", "--name-only", "--format=").split() == ["res/a.json"]
    assert "other.txt" in git("status", "--porcelain")  # left as it was
    assert not gitcommit.commit_results([str(tmp_path / "res" / "a.json")], "again")  # unchanged: no commit
    assert git("log", "-1", "--format=%s").strip() == "Table 1 (smoke): x; resume: python ..."


def test_seed_runs_groups_consecutive_seeds():
    assert table1_units.seed_runs([2, 0, 1]) == [(0, 3)]
    assert table1_units.seed_runs({0, 2, 3, 5}) == [(0, 1), (2, 2), (5, 1)]
    assert table1_units.seed_runs([]) == []


def test_sweep_groups_skips_and_aggregates_partial_results(table1, tmp_path):
    calls, resumed = [], []

    def fake_train(cfg, resume=False, verbose=False):
        calls.append((cfg.env, cfg.dataset, cfg.method, cfg.seed, cfg.seeds, os.path.basename(cfg.out)))
        resumed.append(resume)
        if "bc" in cfg.methods and cfg.seed + cfg.seeds > 1:  # any program that trains seed 1 of BC
            raise RuntimeError("simulated crash")
        if cfg.method == "minsubdt,bc" and cfg.seed == 0:  # the first program logs one evaluation of its models
            os.makedirs(cfg.out)
            with open(os.path.join(cfg.out, "metrics.jsonl"), "w") as f:
                f.write(json.dumps({"step": 1, "loss": 1.0, "loss_per_model": [1.5, 0.5]}) + "\n" + json.dumps(
                    {"step": 1, "final": True, "eval_method": ["minsubdt", "bc"], "eval_seed": [0, 0],
                     "eval_normalized_score": [50.0, 30.0], "eval_min_subdominance": [1.0, 1.0]}) + "\n")
        return fake_results(cfg)

    kw = dict(preset="smoke", envs=("hopper",), datasets=("medium",), runs_root=str(tmp_path / "runs"),
              results_root=str(tmp_path / "res"), train_fn=fake_train, log=lambda *_: None)
    cut = tmp_path / "runs" / "smoke" / "hopper-medium-dt-s0-1"  # cut before its first checkpoint: starts again
    (cut / "checkpoints").mkdir(parents=True)
    (cut / "config.json").write_text("{}")
    st = table1.run_sweep(methods=("minsubdt", "bc"), seeds=(0,), **kw)
    # methods missing the same seeds are one program, written one file per model
    assert calls == [("hopper", "medium", "minsubdt,bc", 0, 1, "hopper-medium-minsubdt+bc-s0")]
    assert st["done"] == ["hopper-medium-minsubdt-s0", "hopper-medium-bc-s0"]
    calls.clear()
    st = table1.run_sweep(methods=("minsubdt", "bc", "minsubdt-learned"), seeds=(0, 1, 2), **kw)
    # finished runs are skipped; the lowest missing seed of every cell first; a crash fails its whole program
    assert calls == [("hopper", "medium", "minsubdt-learned", 0, 3, "hopper-medium-minsubdt-learned-s0-2"),
                     ("hopper", "medium", "minsubdt,bc", 1, 2, "hopper-medium-minsubdt+bc-s1-2")]
    assert len(st["skipped"]) == 2 and st["failed"] == ["hopper-medium-minsubdt-s1", "hopper-medium-minsubdt-s2",
                                                        "hopper-medium-bc-s1", "hopper-medium-bc-s2"]
    calls.clear()
    resumed.clear()
    (tmp_path / "runs" / "smoke" / "hopper-medium-minsubdt+bc-s1" / "checkpoints" / "3").mkdir(parents=True)
    st = table1.run_sweep(methods=("minsubdt", "bc", "minsubdt-learned", "dt"), seeds=(0, 1), **kw)
    assert calls == [("hopper", "medium", "dt", 0, 2, "hopper-medium-dt-s0-1"),
                     ("hopper", "medium", "minsubdt,bc", 1, 1, "hopper-medium-minsubdt+bc-s1")]
    assert resumed == [False, True]  # resumed where a checkpoint is
    assert len(st["skipped"]) == 4 and st["failed"] == ["hopper-medium-minsubdt-s1", "hopper-medium-bc-s1"]
    # a model's file reads as that model's single run, its own data summary included
    res_dir = tmp_path / "res" / "table1" / "smoke"
    r2 = json.loads((res_dir / "hopper-medium-minsubdt-learned-s2.json").read_text())
    assert r2["config"]["seed"] == 2 and r2["config"]["seeds"] == 1 and r2["config"]["method"] == "minsubdt-learned"
    assert r2["eval"]["normalized_score_mean"] == 42.0
    assert r2["dataset"]["learned_costs"]["heldout_pair_accuracy"] == pytest.approx(0.82)
    assert "dataset_per_model" not in r2 and "eval_per_model" not in r2 and "eval_per_seed" not in r2 and r2["dataset"]["costs_sample"]
    bc0 = json.loads((res_dir / "hopper-medium-bc-s0.json").read_text())
    assert bc0["config"]["method"] == "bc" and bc0["eval"]["normalized_score_mean"] == 30.0
    assert bc0["curve"]["normalized_score"] == [30.0] and bc0["curve"]["loss"] == [0.5]  # its own model's curve
    assert "curve" not in r2  # its program logged no evaluation

    out = table1.aggregate("smoke", results_root=str(tmp_path / "res"), out_root=str(tmp_path / "agg"), plots=True,
                           runs_root=str(tmp_path / "runs"))
    cell = out["table"]["medium/hopper"]
    assert cell["minsubdt-learned"]["mean"] == pytest.approx(41.0)
    assert cell["minsubdt-learned"]["std"] == pytest.approx(np.std([0, 1, 2]))
    assert cell["minsubdt-learned"]["n_seeds"] == 3 and cell["bc"]["n_seeds"] == 1 and cell["bc"]["mean"] == 30.0
    assert cell["dt"]["better_than_mean_demo_share"] == pytest.approx(0.55) and cell["dt"]["n_seeds"] == 2
    av = out["averages"]["all"]
    assert av["minsubdt"]["cells"] == 1 and av["minsubdt"]["of"] == 9
    md = (tmp_path / "agg" / "table1.md").read_text()
    assert out["cost_rank_agreement"]["medium/hopper"]["engineered_spearman"] == 0.9
    assert "41.0 ± 0.8 (3)" in md and "30.0 (1 seed)" in md and "± 0.0" not in md and "Published" in md
    assert (tmp_path / "agg" / "table1_costs_hopper.png").exists()
    assert json.loads((tmp_path / "agg" / "table1.json").read_text())["runs"] == 7
    files = os.listdir(res_dir)  # every result file is complete JSON (written atomically)
    assert len(files) == 7 and not any(f.endswith(".tmp") for f in files)
    assert np.isclose(json.loads((res_dir / "hopper-medium-dt-s1.json").read_text())["eval"]["normalized_score_mean"],
                      61.0)
    # a cell whose runs used two recordings: the dataset's own score is their mean, each recording counted once
    bc0["dataset"].update(path="/c/hopper-medium-b.hdf5", sha256="b" * 64, normalized_score_mean=55.0)
    (res_dir / "hopper-medium-bc-s0.json").write_text(json.dumps(bc0))
    dt1 = json.loads((res_dir / "hopper-medium-dt-s1.json").read_text())  # DT's seeds span the two recordings
    dt1["dataset"].update(path="/c/hopper-medium-b.hdf5", sha256="b" * 64, normalized_score_mean=55.0)
    (res_dir / "hopper-medium-dt-s1.json").write_text(json.dumps(dt1))
    out = table1.aggregate("smoke", results_root=str(tmp_path / "res"), out_root=str(tmp_path / "agg2"), plots=False)
    assert out["dataset_score"]["medium/hopper"] == pytest.approx(50.0)  # (45 + 55) / 2, not 6 x 45 + 55 over 7
    assert [(f["dataset_score"], f["methods"]) for f in out["data_files"]["medium/hopper"]] == [
        (45.0, ["minsubdt", "minsubdt-learned", "dt"]), (55.0, ["dt", "bc"])]
    assert [f["seeds"]["dt"] for f in out["data_files"]["medium/hopper"]] == [[0], [1]]
    md = (tmp_path / "agg2" / "table1.md").read_text()
    assert "| medium | hopper | 50.0 (mean of 2 recordings) |" in md
    assert "used by MinSubDT (engg. costs), MinSubDT (learned costs), DT [seed 0]; " in md
    assert "used by DT [seed 1], BC (DT architecture) |" in md


def test_critic_columns_train_by_agent_and_show_beside_the_seeds_cql(table1, tmp_path):
    """``--methods cql iql minsubdt-iql``: one program per agent (IQL's two methods together), and the report gains
    their columns, with the seed's published CQL, BEAR, BRAC-v and AWR columns beside ours."""
    calls = []

    def fake_train(cfg, resume=False, verbose=False):
        calls.append((cfg.method, cfg.seeds))
        return fake_results(cfg)

    kw = dict(preset="smoke", envs=("hopper",), datasets=("medium",), runs_root=str(tmp_path / "runs"),
              results_root=str(tmp_path / "res"), train_fn=fake_train, log=lambda *_: None)
    table1.run_sweep(methods=("minsubdt", "cql", "iql", "minsubdt-iql"), seeds=(0, 1), **kw)
    assert sorted(calls) == [("cql", 2), ("iql,minsubdt-iql", 2), ("minsubdt", 2)]
    out = table1.aggregate("smoke", results_root=str(tmp_path / "res"), out_root=str(tmp_path / "agg"), plots=False)
    assert out["table"]["medium/hopper"]["cql"]["n_seeds"] == 2
    md = (tmp_path / "agg" / "table1.md").read_text()
    header = next(line for line in md.splitlines() if line.startswith("| dataset | env | dataset's own"))
    assert header.endswith("| CQL | IQL | MinSubDT-IQL |") and "TD3+BC" not in header
    assert "| medium | hopper | 56.8 | 55.8 | 67.6 | 63.9 | 58.0 | 52.1 | 31.1 | 35.9 |" in md  # the seed's row


def test_study_trains_each_agent_family_at_its_own_setting_and_refuses_an_unset_critic(table1, tmp_path, capsys,
                                                                                       monkeypatch):
    """At ``--preset study`` the DT family's program gets the study preset (cosine, EMA, 10k steps) and a critic
    agent the setting its own curve chose (``AgentInfo.presets``, here one given to IQL); a critic agent without one
    is one error before anything trains or is written, from the command line and from ``run_sweep``."""
    monkeypatch.setitem(AGENTS["iql"].presets, "study", dict(steps=1234, lr_schedule="constant", ema_decay=0.0))
    cfgs = []

    def fake_train(cfg, resume=False, verbose=False):
        cfgs.append(cfg)
        return fake_results(cfg)

    table1.run_sweep(preset="study", envs=("hopper",), datasets=("medium",), methods=("dt", "iql"), seeds=(0,),
                     runs_root=str(tmp_path / "runs"), results_root=str(tmp_path / "res"), train_fn=fake_train,
                     log=lambda *_: None)
    by = {c.method: c for c in cfgs}
    assert (by["dt"].steps, by["dt"].lr_schedule, by["dt"].ema_decay) == (PRESETS["study"].steps, "cosine", 0.999)
    assert (by["iql"].steps, by["iql"].lr_schedule, by["iql"].ema_decay) == (1234, "constant", 0.0)
    assert by["iql"].eval_episodes == by["dt"].eval_episodes == 100
    table1.aggregate("study", results_root=str(tmp_path / "res"), out_root=str(tmp_path / "agg"), plots=False)
    assert "iql: 1,234 steps at its reference's rates" in (tmp_path / "agg" / "table1.md").read_text()
    with pytest.raises(SystemExit) as e:
        table1.main(["run", "--preset", "study", "--methods", "iql", "cql", "--runs-root", str(tmp_path / "no")])
    assert e.value.code == 2 and "no setting for cql" in capsys.readouterr().err
    assert not (tmp_path / "no").exists()
    with pytest.raises(ValueError, match="no setting for cql"):  # the library call too, before anything is written
        table1.run_sweep(preset="study", methods=("cql",), runs_root=str(tmp_path / "no"),
                         results_root=str(tmp_path / "no"), train_fn=fake_train)
    assert not (tmp_path / "no").exists()


def test_a_result_trained_with_another_config_is_an_error_not_kept(table1, tmp_path, monkeypatch):
    """A result file that the sweep would skip as done but that was trained with another config than the preset's
    now (a changed preset) is one error naming the file and the field, before anything trains or is written; one
    that differs only in how it was run (its program's seeds, chunking), or a critic agent's in a DT-family field
    it does not read, is kept and skipped."""
    calls, kw = recording_sweep(tmp_path)
    table1.run_sweep(methods=("dt", "iql"), seeds=(0, 1), **kw)
    calls.clear()
    table1.run_sweep(methods=("dt", "iql"), seeds=(0, 1, 2), chunk_steps=5, **kw)  # another chunking: kept
    assert calls == [("dt", 2, 1), ("iql", 2, 1)]
    res = tmp_path / "res" / "table1" / "smoke"
    before = {f: (res / f).read_text() for f in os.listdir(res)}
    monkeypatch.setitem(PRESETS, "smoke", dataclasses.replace(PRESETS["smoke"], learning_rate=5e-4))
    calls.clear()
    with pytest.raises(ValueError, match=r"3 result file\(s\).*hopper-medium-dt-s0: learning_rate 0.001 \(now "
                                         r"0.0005\)"):
        table1.run_sweep(methods=("iql", "dt"), seeds=(0, 1, 2, 3), **kw)
    assert calls == [] and {f: (res / f).read_text() for f in os.listdir(res)} == before
    table1.run_sweep(methods=("iql",), seeds=(0, 1, 2, 3), **kw)  # IQL does not read the DT family's rate
    assert calls == [("iql", 3, 1)]


def test_a_dt_result_of_an_earlier_model_revision_is_an_error_not_kept(table1, tmp_path):
    """Issue 54: a DT-family result file from before the return-embedding fix (no ``dt_revision``: revision 1) would
    be kept as the sweep's result like a changed preset's: one error naming it, nothing trained; a critic agent's
    file of the same age is kept (its networks did not change)."""
    calls, kw = recording_sweep(tmp_path)
    table1.run_sweep(methods=("dt", "iql"), seeds=(0,), **kw)
    res = tmp_path / "res" / "table1" / "smoke"
    for f in res.glob("*.json"):
        r = json.loads(f.read_text())
        if r.pop("dt_revision", None) is not None:
            f.write_text(json.dumps(r))
    calls.clear()
    with pytest.raises(ValueError, match=r"1 result file\(s\).*hopper-medium-dt-s0: dt_revision 1 \(now 2\)"):
        table1.run_sweep(methods=("dt", "iql"), seeds=(0, 1), **kw)
    assert calls == []
    table1.run_sweep(methods=("iql",), seeds=(0, 1), **kw)
    assert calls == [("iql", 1, 1)]


def test_ctrl_c_stops_the_sweep_not_only_its_unit(table1, tmp_path, monkeypatch, capsys):
    """A Ctrl-C in a unit (train's ``Interrupted``, raised after that unit's checkpoint) was counted as one failed
    unit, and the sweep went on to train the next one. It stops the sweep; the command line says so in one line,
    with the sweep's own resume command (exit 130)."""
    calls = []

    def pressed(cfg, resume=False, verbose=False):
        calls.append(cfg.dataset)
        raise Interrupted("stopped after the checkpoint at step 10 of 20; resume with: ...")

    with pytest.raises(Interrupted):
        table1.run_sweep(preset="smoke", envs=("hopper",), datasets=("medium", "medium-replay"), methods=("dt",),
                         seeds=(0,), runs_root=str(tmp_path / "runs"), results_root=str(tmp_path / "res"),
                         train_fn=pressed, log=lambda *_: None)
    assert calls == ["medium"]  # the second unit never started

    def sweep(*args, **kwargs):
        raise Interrupted("...")

    monkeypatch.setattr(table1, "run_sweep", sweep)
    assert table1.main(["run", "--preset", "smoke", "--envs", "hopper", "--methods", "dt", "--seeds", "0"]) == 130
    err = capsys.readouterr().err
    assert err.startswith("interrupted: the sweep stopped") and err.count("\n") == 1
    assert "resume with: python experiments/table1.py run --preset smoke --envs hopper --methods dt --seeds 0" in err


def test_a_negative_seed_is_one_error_not_a_sweep_of_failures(table1, monkeypatch, capsys):
    """'--seeds -1' ran every unit and reported 36 failures; it is one error line before anything runs."""
    monkeypatch.setattr(table1, "run_sweep", lambda *a, **k: pytest.fail("the sweep ran"))
    with pytest.raises(SystemExit) as e:
        table1.main(["run", "--preset", "smoke", "--seeds", "0", "-1"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "--seeds must be >= 0" in err and "Traceback" not in err
