"""Methods as records and agents as folders: the MLP behaviour-cloning agent learns, runs through the same loop,
evaluation and results layout as the DT, and each method's record makes its return tokens."""

import dataclasses
import json

import jax
import numpy as np
import orbax.checkpoint as ocp
import pytest

from minsubdt_jax.agents import AGENTS, make_agent
from minsubdt_jax.agents.base import init_state, make_optimizer, make_train_chunk
from minsubdt_jax.config import PRESETS, validate
from minsubdt_jax.train import parse_args
from minsubdt_jax.costs import engineered_costs
from minsubdt_jax.data import Trajectories, sampler_data
from minsubdt_jax.methods import METHODS, RETURNS_ALIASES, get_method
from minsubdt_jax.pipeline import prepare
from minsubdt_jax.subdominance import min_subdominance


def test_every_method_names_a_registered_agent_and_returns_aliases_map_to_methods():
    assert {m.agent for m in METHODS.values()} <= set(AGENTS)
    assert RETURNS_ALIASES == {"subdom": "minsubdt", "learned": "minsubdt-learned", "true": "dt", "none": "bc"}
    assert parse_args(["--returns", "true"])[0].method == "dt"
    assert parse_args(["--method", "bc-mlp"])[0].method == "bc-mlp"
    # --lr is the field's usual name (and curves.py's): it sets the rate, not an abbreviation of --lr-schedule
    assert parse_args(["--lr", "3e-4"])[0].learning_rate == 3e-4
    with pytest.raises(ValueError, match="--method must be one of"):
        get_method("no-such-method")


def test_mlp_agent_learns_a_state_to_action_map():
    """Actions a = tanh(W s) of the state: after 400 steps the MLP predicts them on new states far better than
    at the start (the loss is the agent's own, through the shared step)."""
    rng = np.random.default_rng(0)
    n, T, obs, act = 16, 50, 5, 2
    W = rng.normal(size=(obs, act))
    states = rng.normal(size=(n, T, obs)).astype(np.float32)
    ds = Trajectories(states, np.tanh(states @ W).astype(np.float32), np.zeros((n, T), np.float32),
                      np.full(n, T, np.int32), np.zeros(n, bool))
    data = sampler_data(ds, np.zeros((n, T)), np.zeros(obs, np.float32), np.ones(obs, np.float32))
    cfg = dataclasses.replace(PRESETS["smoke"], mlp_hidden=64, learning_rate=3e-3, warmup_steps=10, batch_size=64)
    agent = make_agent("mlp", cfg, obs, act, T)
    assert agent.context_len == 1 and agent.initial_carry(4) == ()
    tx = make_optimizer(cfg)
    state = init_state(agent, tx, jax.random.PRNGKey(0))
    test = rng.normal(size=(200, obs)).astype(np.float32)
    err = lambda p: float(np.mean((np.asarray(agent.model.apply(p, test)) - np.tanh(test @ W)) ** 2))  # noqa: E731
    before = err(state.params)
    state, losses = make_train_chunk(agent, tx, cfg.batch_size, 400)(state, data)
    assert err(state.params) < 0.05 * before and float(losses[-50:].mean()) < 0.05 * float(losses[:10].mean())


def test_methods_make_their_return_tokens(small_dataset_path):
    """minsubdt: -min-subdominance (eq. 2, engineered costs, leave-one-out) at every step of an episode; dt: the
    true returns-to-go / 1000 and the dataset's best return as target; dt-total: the episode's return / 1000 at every
    step, the same target; dt-tied: dt-total's tokens, but the demos at min-subdominance K * beta share their mean
    return; bc and bc-mlp: zeros."""
    base = dataclasses.replace(PRESETS["smoke"], env="hopper", dataset=small_dataset_path, episode_length=60)
    preps = {m: prepare(validate(dataclasses.replace(base, method=m)), get_method(m), verbose=False)
             for m in ("minsubdt", "dt", "dt-total", "dt-tied", "bc-mlp")}
    data = preps["dt"].source.data
    valid = data.valid_mask()
    f = np.asarray(engineered_costs("hopper", data.observations, data.lengths, 60, terminated=data.terminals))
    ms = np.asarray(min_subdominance(f, f, leave_one_out=True).value)
    rtg = np.asarray(preps["minsubdt"].sampler.returns_to_go)
    np.testing.assert_allclose(rtg, np.where(valid, -ms[:, None], 0.0), rtol=1e-6)
    true_rtg = np.flip(np.cumsum(np.flip(data.rewards, 1), 1), 1) / 1000.0
    np.testing.assert_allclose(np.asarray(preps["dt"].sampler.returns_to_go), np.where(valid, true_rtg, 0), rtol=1e-5,
                               atol=1e-6)
    assert preps["dt"].target_return == pytest.approx(float(data.returns.max())) and preps["minsubdt"].target_return == 0
    np.testing.assert_allclose(np.asarray(preps["dt-total"].sampler.returns_to_go),
                               np.where(valid, true_rtg[:, :1], 0), rtol=1e-5, atol=1e-6)
    assert preps["dt-total"].target_return == pytest.approx(preps["dt"].target_return)
    tied = np.isclose(ms, 2 * base.beta)  # alpha = 0 in both engineered metrics
    assert 2 <= tied.sum() < len(ms)  # the data has a tie to pool, and demos outside it
    labels = np.where(tied, data.returns[tied].mean(), data.returns) / 1000.0
    np.testing.assert_allclose(np.asarray(preps["dt-tied"].sampler.returns_to_go), np.where(valid, labels[:, None], 0),
                               rtol=1e-5, atol=1e-6)
    assert preps["dt-tied"].target_return == pytest.approx(preps["dt"].target_return)
    assert not np.asarray(preps["bc-mlp"].sampler.returns_to_go).any()


def test_bc_mlp_trains_and_is_evaluated_like_the_dt(tmp_path, small_dataset_path):
    """The non-DT agent in the same run loop: checkpoints, periodic and final evaluation in MJX, the same
    results.json layout as a DT run, and every metrics record passed to progress_fn."""
    from minsubdt_jax.train import train

    cfg = dataclasses.replace(PRESETS["smoke"], env="hopper", dataset=small_dataset_path, episode_length=60,
                              method="bc-mlp", eval_every=10, out=str(tmp_path / "mlp"))
    seen = []
    res = train(validate(cfg), verbose=False, progress_fn=lambda step, rec: seen.append((step, sorted(rec))))
    assert res["method"] == {"name": "bc-mlp", "label": "BC (MLP)", "agent": "mlp"}
    ev = res["eval"]
    assert ev["episodes"] == 3 and np.isfinite(ev["normalized_score_mean"]) and 0 <= ev["min_subdominance_mean"] <= 2
    assert set(res) == {"config", "method", "dataset", "references", "physics", "platform", "seeds", "models",
                        "train", "eval_per_model", "eval", "dt_revision"}
    assert res["physics"]["physics"] == "mujoco" and res["physics"]["dynamics"] == "brax"  # auto on the CPU
    assert set(ev) >= {"returns", "costs", "normalized_score_std", "better_than_mean_demo_share", "seconds"}
    records = [json.loads(ln) for ln in open(tmp_path / "mlp" / "metrics.jsonl")]
    assert [(r["step"], sorted(r)) for r in records] == seen
    assert [r["step"] for r in records if "eval_normalized_score" in r] == [10, 20]
    params = ocp.CheckpointManager(str(tmp_path / "mlp" / "checkpoints")).restore(20)["params"]
    assert (1, 11, 256) in [np.shape(p) for p in jax.tree.leaves(params)]  # [seeds, obs, hidden]: the MLP's layer


def test_cosine_schedule_and_parameter_average_against_hand_computation():
    """lr: linear warm-up, then constant or a cosine from the peak to 0 at --steps (hand values). EMA: a 6-step
    chunk keeps e_t = d_t e_{t-1} + (1 - d_t) p_t with d_t = min(d, (1 + t) / (10 + t)), recomputed here step by
    step from the raw parameters of single jitted steps; the raw parameters are the same as without an EMA."""
    from minsubdt_jax.agents.base import eval_params, learning_rate, make_train_step

    cfg = dataclasses.replace(PRESETS["smoke"], learning_rate=1e-3, warmup_steps=10, steps=110, mlp_hidden=8,
                              batch_size=4)
    cos = dataclasses.replace(cfg, lr_schedule="cosine")
    lr = lambda c, t: float(learning_rate(c, t))  # noqa: E731
    assert lr(cfg, 4) == pytest.approx(5e-4) and lr(cfg, 100) == pytest.approx(1e-3)
    assert lr(cos, 4) == pytest.approx(5e-4) and lr(cos, 10) == pytest.approx(1e-3)
    assert lr(cos, 60) == pytest.approx(5e-4) and lr(cos, 35) == pytest.approx(1e-3 * (1 + np.cos(np.pi / 4)) / 2)
    assert lr(cos, 110) == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match="--lr-schedule must be one of"):
        validate(dataclasses.replace(cfg, lr_schedule="linear"))
    with pytest.raises(ValueError, match="--ema-decay must be in"):
        validate(dataclasses.replace(cfg, ema_decay=1.0))

    rng = np.random.default_rng(1)
    n, T, obs, act = 4, 10, 3, 2
    ds = Trajectories(rng.normal(size=(n, T, obs)).astype(np.float32), rng.uniform(-1, 1, (n, T, act)).astype(
        np.float32), np.zeros((n, T), np.float32), np.full(n, T, np.int32), np.zeros(n, bool))
    data = sampler_data(ds, np.zeros((n, T)), np.zeros(obs, np.float32), np.ones(obs, np.float32))
    agent, tx, d = make_agent("mlp", cfg, obs, act, T), make_optimizer(cos), 0.5
    plain = init_state(agent, tx, jax.random.PRNGKey(0))
    state = init_state(agent, tx, jax.random.PRNGKey(0), ema=True)
    step = jax.jit(make_train_step(agent, tx, cfg.batch_size))
    ema = plain.params
    for t in range(6):
        plain, _ = step(plain, data)
        dt = min(d, (1 + t) / (10 + t))
        ema = jax.tree.map(lambda e, p: dt * e + (1 - dt) * p, ema, plain.params)
    state, _ = make_train_chunk(agent, tx, cfg.batch_size, 6, ema_decay=d)(state, data)
    for a, b in zip(jax.tree.leaves(state.params), jax.tree.leaves(plain.params)):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
    for a, b in zip(jax.tree.leaves(eval_params(state)), jax.tree.leaves(ema)):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
    assert not np.allclose(jax.tree.leaves(eval_params(state))[0], jax.tree.leaves(state.params)[0])


def test_each_agent_declares_exactly_the_agent_settings_it_reads():
    """``AgentInfo.fields`` decides which config fields the experiments compare (a stale result, curve files that
    pool): an agent that read another agent's setting without declaring it would let two different results count as
    one. Recorded reads of a config while the agent is built, sized and its optimiser traced (a cosine schedule,
    which reads every schedule field; a critic agent's rates are read as it is built) must hit, among the fields of agents' settings, exactly the declared ones."""
    from minsubdt_jax.agents import batch_size_of
    from minsubdt_jax.agents.base import optimizer_for

    cfg = dataclasses.replace(PRESETS["smoke"], lr_schedule="cosine")
    agent_only = frozenset().union(*(a.fields for a in AGENTS.values()))
    for name, info in AGENTS.items():
        seen = set()

        class Reads:
            def __getattr__(self, field):
                seen.add(field)
                return getattr(cfg, field)

        agent = make_agent(name, Reads(), 17, 6, 1000)
        batch_size_of(name, Reads())
        tx = optimizer_for(agent, Reads())
        params = jax.eval_shape(agent.init_params, jax.random.key(0))
        if info.transitions:  # a critic agent's rates are read when it is built; its networks update one by one
            jax.eval_shape(tx.init, params)
        else:
            jax.eval_shape(lambda p: tx.update(p, tx.init(p), p), params)
        assert seen & agent_only == info.fields, (name, sorted(seen & agent_only), sorted(info.fields))
    from minsubdt_jax.runsetup import check_agent_settings  # the run refuses a setting its agent does not read

    with pytest.raises(ValueError, match="--precision bf16 is for the DT and the critic agents"):
        check_agent_settings(dataclasses.replace(cfg, method="bc-mlp", precision="bf16"), "mlp")
    assert check_agent_settings(dataclasses.replace(cfg, method="iql", precision="bf16"), "iql") is AGENTS["iql"]


def test_an_agents_per_dataset_settings_fill_what_the_config_leaves_unset():
    """BEAR's kernel is an agent's setting, not an env's (issue 75): its record chooses it per env as its
    reference did (gaussian for halfcheetah, laplacian for the others and for a new env), and a config that sets
    it wins."""
    import dataclasses

    from minsubdt_jax.agents import AGENTS, make_agent
    from minsubdt_jax.config import PRESETS

    def kernel(**kw):
        return make_agent("bear", dataclasses.replace(PRESETS["smoke"], method="bear", **kw), 17, 6, 100).kernel

    assert [kernel(env=e) for e in ("halfcheetah", "walker2d", "hopper")] == ["gaussian", "laplacian", "laplacian"]
    assert kernel(env="halfcheetah", bear_kernel="laplacian") == "laplacian"
    info = AGENTS["bear"]
    assert info.settings_for("swimmer", "medium") == {"bear_kernel": "laplacian"}
    specific = dataclasses.replace(info, data_settings={**info.data_settings,
                                                        ("halfcheetah", "medium"): {"bear_kernel": "laplacian"}})
    assert specific.settings_for("halfcheetah", "medium")["bear_kernel"] == "laplacian"
    assert specific.settings_for("halfcheetah", "expert")["bear_kernel"] == "gaussian"
