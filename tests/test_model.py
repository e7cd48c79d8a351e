import jax
import jax.numpy as jnp
import numpy as np

from minsubdt_jax.model import DecisionTransformer

B, K, OBS, ACT = 2, 6, 5, 3


def _inputs(seed=0):
    r = np.random.default_rng(seed)
    return dict(states=jnp.asarray(r.normal(size=(B, K, OBS)), jnp.float32),
                actions=jnp.asarray(r.uniform(-1, 1, (B, K, ACT)), jnp.float32),
                returns_to_go=jnp.asarray(r.normal(size=(B, K)), jnp.float32),
                timesteps=jnp.tile(jnp.arange(K), (B, 1)), mask=jnp.ones((B, K), bool))


def _model_and_params():
    model = DecisionTransformer(act_dim=ACT, embed_dim=32, n_layers=2, n_heads=2, dropout=0.0, max_timestep=50)
    x = _inputs()
    return model, model.init(jax.random.PRNGKey(0), **x)


def test_shapes_and_range():
    model, params = _model_and_params()
    out = model.apply(params, **_inputs())
    assert out.shape == (B, K, ACT) and bool(jnp.all(jnp.abs(out) <= 1))


def test_causal_later_tokens_do_not_change_earlier_predictions():
    model, params = _model_and_params()
    x = _inputs()
    base = model.apply(params, **x)
    j = 3
    for key in ("states", "actions", "returns_to_go"):
        y = dict(x)
        y[key] = x[key].at[:, j + 1:].add(5.0)
        out = model.apply(params, **y)
        np.testing.assert_allclose(out[:, :j + 1], base[:, :j + 1], atol=1e-5)
        assert not np.allclose(out[:, j + 1:], base[:, j + 1:])
    # a_j itself comes after s_j: changing a_j must not change the prediction at step j
    y = dict(x); y["actions"] = x["actions"].at[:, j].add(5.0)
    np.testing.assert_allclose(model.apply(params, **y)[:, :j + 1], base[:, :j + 1], atol=1e-5)
    # but R_j and s_j do
    y = dict(x); y["states"] = x["states"].at[:, j].add(5.0)
    assert not np.allclose(model.apply(params, **y)[:, j], base[:, j])


def test_padding_is_ignored():
    """Left-padded tokens, whatever their content, do not change the predictions at real steps."""
    model, params = _model_and_params()
    x = _inputs()
    mask = jnp.tile(jnp.arange(K) >= 2, (B, 1))
    x["mask"] = mask
    base = model.apply(params, **x)
    y = dict(x)
    for key in ("states", "actions", "returns_to_go"):
        y[key] = x[key].at[:, :2].set(123.0)
    np.testing.assert_allclose(model.apply(params, **y)[:, 2:], base[:, 2:], atol=1e-5)
    # and equals running the model on the real part alone (time embedding identical)
    short = {k: v[:, 2:] for k, v in x.items()}
    np.testing.assert_allclose(model.apply(params, **short), base[:, 2:], atol=1e-5)
