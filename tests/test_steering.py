"""Issue 55: metrics that steer. A return token per metric (``minsubdt-vec``) chosen at deployment moves the achieved
metrics the way it asks; a trained run is evaluated at a target of one's choosing (``python -m
minsubdt_jax.evaluate``) and acts in a gymnasium loop (``load_policy``)."""

import json
import os
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from minsubdt_jax.costs import CostMetric, trajectory_costs
from minsubdt_jax.methods import METHODS
from minsubdt_jax.subdominance import min_subdominance, returns_to_go


def test_per_metric_tokens_steer_two_conflicting_metrics():
    """A toy offline dataset where two metrics conflict exactly: ``push`` costs the first action coordinate, ``pull``
    its negation. Each episode keeps one action ``a`` in [-0.8, 0.8]; states are noise. ``minsubdt-vec``'s tokens
    are eq. 2's per-metric terms (hand check: the episode with the lowest ``a`` has term 0 in ``push`` and beta in
    ``pull``). After 300 smoke steps (2 seeds) the policy asked to beat every demo in ``push`` (target push=0,
    pull=beta) takes a low action, asked the reverse a high one, asked half of each one between: the achieved
    ``push`` cost follows the target in the asked order, by a margin."""
    from minsubdt_jax.agents import make_agent
    from minsubdt_jax.agents.base import PolicyInputs, init_seed_states, make_optimizer, make_train_chunk
    from minsubdt_jax.config import PRESETS
    from minsubdt_jax.data import Trajectories, sampler_data

    rng = np.random.default_rng(0)
    n, T, obs, act, beta = 40, 30, 3, 2, 1.0
    a0 = np.linspace(-0.8, 0.8, n)[rng.permutation(n)]
    states = rng.normal(size=(n, T, obs)).astype(np.float32)
    actions = np.broadcast_to(a0[:, None, None], (n, T, act)).astype(np.float32)
    ds = Trajectories(states, actions, np.zeros((n, T), np.float32), np.full(n, T, np.int32), np.zeros(n, bool))
    metrics = (CostMetric("push", lambda o, a: a[..., 0], -1.0, 1.0, uses_actions=True),
               CostMetric("pull", lambda o, a: -a[..., 0], -1.0, 1.0, uses_actions=True))
    costs = np.asarray(trajectory_costs(metrics, states, ds.lengths, T, terminated=ds.terminals, actions=actions))
    sub = min_subdominance(costs, costs, beta, leave_one_out=True)
    rewards = METHODS["minsubdt-vec"].rewards(ds, sub, costs)  # [n, T, 2]: -terms at the last step
    lo = np.argmin(a0)
    np.testing.assert_allclose(rewards[lo, -1], [0.0, -beta], atol=1e-6)
    assert np.all(rewards[:, :-1] == 0)
    rtg = np.asarray(returns_to_go(rewards, ds.lengths))
    cfg = PRESETS["smoke"]
    agent, tx = make_agent("dt", cfg, obs, act, T, return_dim=2), make_optimizer(cfg)
    train = make_train_chunk(agent, tx, 32, 300, seed_axis=True)
    state, _ = train(init_seed_states(agent, tx, range(2)), sampler_data(ds, rtg, np.zeros(obs), np.ones(obs)))

    episodes, steps = 6, 8
    test_states = jnp.asarray(rng.normal(size=(steps, 3 * episodes, obs)), jnp.float32)
    asked = np.repeat([[0.0, beta], [beta / 2, beta / 2], [beta, 0.0]], episodes, axis=0)  # push, pull terms

    @jax.jit
    @jax.vmap
    def roll(params):
        ctx, taken = agent.initial_carry(3 * episodes), []
        for t in range(steps):
            inputs = PolicyInputs(params, jnp.zeros(obs), jnp.ones(obs), jnp.asarray(-asked, jnp.float32),
                                  jnp.float32(1.0), jnp.float32(0.0))
            ctx, a = agent.policy(inputs, ctx, test_states[t], jnp.zeros(3 * episodes), t, None)
            taken.append(a[:, 0])
        return jnp.stack(taken)  # [steps, 3 * episodes]

    push = (np.asarray(roll(state.params)).reshape(2, steps, 3, episodes) + 1) / 2  # achieved push cost per step
    per_target = push.mean(axis=(1, 3))  # [seeds, 3 targets]
    assert np.all(np.diff(per_target, axis=1) > 0.1), per_target  # in the asked order, by > 0.2 in a
    assert np.all(per_target[:, 0] < 0.3) and np.all(per_target[:, 2] > 0.7), per_target


@pytest.fixture(scope="module")
def vec_run(tmp_path_factory, small_dataset_path):
    from minsubdt_jax.train import main

    out = tmp_path_factory.mktemp("runs") / "vec"
    assert main(["--preset", "smoke", "--env", "hopper", "--episode-length", "60", "--dataset", small_dataset_path,
                 "--method", "minsubdt-vec", "--costs", "x_velocity,energy@lived", "--out", str(out)]) == 0
    return str(out)


def test_evaluate_reproduces_the_run_at_its_default_target_and_writes_beside_it(vec_run, capsys):
    """``python -m minsubdt_jax.evaluate RUN --target x_velocity=0,energy@lived=0``, the method's default target,
    rolls out the same episodes as the run's own final evaluation (same checkpoint, same episode seeds): the same
    scores to the last digit. Another target is other episodes, written beside the first."""
    from minsubdt_jax.evaluate import main

    assert main([vec_run, "--target", "x_velocity=0,energy@lived=0", "--episodes", "3"]) == 0
    assert "minsubdt-vec at x_velocity=0,energy@lived=0" in capsys.readouterr().out
    with open(os.path.join(vec_run, "results.json")) as f:
        res = json.load(f)
    path = os.path.join(vec_run, "evaluations", "minsubdt-vec", "x_velocity=0,energy@lived=0.json")
    with open(path) as f:
        ev = json.load(f)
    assert ev["target"] == {"x_velocity": 0.0, "energy@lived": 0.0} and ev["checkpoint_step"] == 20
    assert ev["eval"]["returns"] == res["eval"]["returns"] and ev["eval"]["costs"] == res["eval"]["costs"]
    assert res["eval"]["target_return"] == [0.0, 0.0]
    assert main([vec_run, "--target", "energy@lived=1", "--episodes", "3"]) == 0
    assert sorted(os.listdir(os.path.dirname(path))) == ["x_velocity=0,energy@lived=0.json",
                                                         "x_velocity=0,energy@lived=1.json"]


@pytest.mark.parametrize("target, says", [("energy=0.5", "'energy' is not a metric of the run"),
                                          ("x_velocity=1.5", "0 to the margin beta"),
                                          ("x_velocity=nan", "must be finite"),
                                          ("x_velocity=0,x_velocity=1", "repeated"),
                                          ("0.5", "takes name=value per metric")])
def test_a_bad_target_is_one_error_line_and_writes_nothing(vec_run, capsys, target, says):
    from minsubdt_jax.evaluate import main

    before = sorted(os.listdir(vec_run))
    assert main([vec_run, "--target", target, "--episodes", "3"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --target") and says in err and err.count("\n") == 1, err
    assert sorted(os.listdir(vec_run)) == before and not os.path.exists(os.path.join(vec_run, "evaluations", "x"))


def test_load_policy_acts_as_the_batched_rollout_does(vec_run):
    """``load_policy`` in a step-by-step loop keeps its own context: fed one recorded episode of the batched rollout
    (C MuJoCo) observation by observation, it takes that episode's actions; and it runs a gymnasium env."""
    import gymnasium as gym

    import minsubdt_jax.envs.gym_env  # noqa: F401  (registers the envs)
    from minsubdt_jax.evaluate import load_policy
    from minsubdt_jax.scoring import rollout_seeds

    policy = load_policy(vec_run, target={"x_velocity": 0.2})
    assert np.allclose(policy.target, [-0.2, 0.0])
    inputs = jax.tree.map(lambda x: jnp.asarray(x)[None], policy.inputs)
    ro = rollout_seeds("hopper", policy.agent.policy, inputs, policy.agent.initial_carry(2), num_episodes=2,
                       horizon=60, seeds=[5], physics="mujoco")
    obs, actions, rewards, length = (np.asarray(x)[0, 0] for x in (ro.observations, ro.actions, ro.rewards,
                                                                    ro.lengths))
    policy.reset()
    taken = [policy(obs[t], rewards[t - 1] if t else 0.0) for t in range(int(length))]
    np.testing.assert_allclose(taken, actions[:length], atol=2e-5)
    env = gym.make("minsubdt/Hopper-brax-v0")
    o, _ = env.reset(seed=0)
    policy.reset()
    for _ in range(5):
        a = policy(o)
        assert a.shape == (3,) and np.all(np.abs(a) <= 1)
        o, *_ = env.step(a)


def test_evaluate_without_a_target_uses_the_runs_own(vec_run, capsys):
    """``--target`` was required: re-scoring a run at its own target (the one its final evaluation used) now needs
    no flag, and rolls out the run's own episodes."""
    from minsubdt_jax.evaluate import main

    assert main([vec_run, "--episodes", "3"]) == 0
    assert "minsubdt-vec at x_velocity=0,energy@lived=0" in capsys.readouterr().out
    with open(os.path.join(vec_run, "evaluations", "minsubdt-vec", "x_velocity=0,energy@lived=0.json")) as f:
        ev = json.load(f)
    with open(os.path.join(vec_run, "results.json")) as f:
        assert ev["eval"]["returns"] == json.load(f)["eval"]["returns"]


def test_evaluate_refuses_an_episode_count_that_cannot_fit_in_memory(vec_run, capsys):
    """``--episodes 100000000`` was killed by the kernel (exit 137) while it allocated the rollout; it is one error
    line that names the memory it would need, and writes nothing."""
    from minsubdt_jax.evaluate import main

    before = sorted(os.listdir(vec_run))
    assert main([vec_run, "--episodes", "100000000"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --episodes 100000000") and "GiB" in err and err.count("\n") == 1, err
    assert sorted(os.listdir(vec_run)) == before


def test_load_policy_says_what_it_expected(vec_run):
    """Fed an observation of the wrong shape, ``load_policy``'s policy failed deep inside JAX; fed NaNs it returned
    NaN actions. Both are one ValueError that says what it takes; a bad target speaks of the argument."""
    from minsubdt_jax.evaluate import load_policy

    policy = load_policy(vec_run)
    with pytest.raises(ValueError, match=r"an observation of shape \(11,\), got \(5,\)"):
        policy(np.zeros(5))
    with pytest.raises(ValueError, match="not finite"):
        policy(np.full(11, np.nan))
    with pytest.raises(ValueError, match="reward.*not finite"):
        policy(np.zeros(11), float("inf"))
    with pytest.raises(ValueError, match=r"^target: 'energy' is not a metric"):
        load_policy(vec_run, target={"energy": 0.5})
    assert policy(np.zeros(11)).shape == (3,)


def test_loading_a_run_checks_it_as_a_resume_does(vec_run, tmp_path, capsys):
    """``evaluate`` reads a run back on the path a resumed training takes (the same checks of its data and cost
    metrics, the same checkpoint manager): a folder without a checkpoint, other cost metrics, or data that changed
    since are one error line each, naming the run, and nothing is written."""
    import shutil

    from minsubdt_jax.evaluate import load_policy, main

    assert main([str(tmp_path), "--episodes", "3"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {tmp_path}: not a run directory") and err.count("\n") == 1, err
    with pytest.raises(ValueError, match="trained on the cost metrics x_velocity, energy@lived.*not on x_velocity, fall"):
        load_policy(vec_run, metrics=["x_velocity", "fall"])
    other = tmp_path / "run"
    shutil.copytree(vec_run, other)
    with open(other / "dataset.json") as f:
        ds = json.load(f)
    with open(other / "dataset.json", "w") as f:
        json.dump(dict(ds, sha256="0" * 64), f)
    before = sorted(os.listdir(other))
    assert main([str(other), "--episodes", "3"]) == 2
    err = capsys.readouterr().err
    assert "the dataset differs from the one the run started on (sha256 000000000000" in err and err.count("\n") == 1
    assert sorted(os.listdir(other)) == before


def test_a_preference_picks_the_datas_episode_that_serves_it_best():
    """By hand: each episode's token is minus its per-metric terms; a preference picks the least weighted term, among
    the episodes labelled nearest it where the data has labels."""
    from types import SimpleNamespace

    from minsubdt_jax.targets import episode_tokens, parse_preference, preference_target

    terms = np.array([[0.1, 0.9], [0.5, 0.4], [0.9, 0.05], [0.3, 0.3]])  # [N, K], lower is better
    prep = SimpleNamespace(sampler=SimpleNamespace(returns_to_go=-terms[:, None, :] / 2.0), rtg_scale=2.0)
    tokens = episode_tokens(prep)
    np.testing.assert_allclose(tokens, -terms)
    pick = lambda w, labels=None: preference_target(tokens, np.array(w), labels)[1]  # noqa: E731
    assert [pick([1, 0]), pick([0, 1]), pick([0.5, 0.5])] == [0, 2, 3]
    np.testing.assert_allclose(preference_target(tokens, np.array([0.5, 0.5]))[0], [-0.3, -0.3])
    labels = np.array([[0.9, 0.1], [0.5, 0.5], [0.9, 0.1], [0.1, 0.9]])
    assert pick([0.5, 0.5], labels) == 1 and pick([0.8, 0.2], labels) == 0  # only the nearest label's episodes
    names = ["x_velocity", "energy@lived"]
    np.testing.assert_allclose(parse_preference("3,1", names), [0.75, 0.25])
    np.testing.assert_allclose(parse_preference({"energy@lived": 2}, names), [0.0, 1.0])
    for bad, says in [("1", "1 weight(s) for the run's 2 metrics"), ("x_velocity=-1", "must be >= 0"),
                      ("0,0", "not all 0"), ("speed=1", "not a metric of the run"), ("x_velocity=1,x_velocity=2",
                                                                                      "repeated")]:
        with pytest.raises(ValueError, match=re.escape(says)):
            parse_preference(bad, names)


def test_evaluate_and_load_policy_take_a_preference(vec_run, capsys):
    """``--preference`` conditions on a data episode's own token (its terms within [0, beta]), written beside the run
    as ``pref-...``; a bad one, or one beside ``--target``, is one error line."""
    from minsubdt_jax.evaluate import load_policy, load_run, main
    from minsubdt_jax.targets import episode_tokens, preference_target

    assert main([vec_run, "--preference", "x_velocity=1", "--episodes", "3"]) == 0
    with open(os.path.join(vec_run, "evaluations", "minsubdt-vec", "pref-x_velocity=1,energy@lived=0.json")) as f:
        ev = json.load(f)
    prep = load_run(vec_run).per_model[0]
    token, i = preference_target(episode_tokens(prep), np.array([1.0, 0.0]))
    assert ev["preference"] == {"x_velocity": 1.0, "energy@lived": 0.0}
    assert ev["target"] == pytest.approx({"x_velocity": -float(token[0]), "energy@lived": -float(token[1])})
    assert 0.0 <= ev["target"]["x_velocity"] <= min(-prep.sampler.returns_to_go[:, 0, 0] * prep.rtg_scale) + 1e-6
    np.testing.assert_allclose(load_policy(vec_run, preference={"x_velocity": 1}).target, token)
    capsys.readouterr()
    for argv, says in [(["--preference", "2,1,1"], "3 weight(s)"), (["--preference", "1,1", "--target", "0.5"],
                                                                     "not both")]:
        assert main([vec_run, *argv, "--episodes", "3"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error:") and says in err and err.count("\n") == 1, err
