"""Our envs as gymnasium envs: one C MuJoCo simulation on the rules of :mod:`~minsubdt_jax.envs.rules`.

    import gymnasium as gym
    import minsubdt_jax.envs.gym_env  # registers minsubdt/Hopper-brax-v0, minsubdt/Walker-d4rl-v0, ...
    env = gym.make("minsubdt/Walker-brax-v0")

For tools that need a gymnasium env: Minari's ``recover_environment`` (our Minari exports name one in their
``env_spec``), d3rlpy's ``get_minari``, or a policy from another library. Resets draw from the same distribution as
our batched rollouts (:func:`~minsubdt_jax.envs.rules.reset_state`, keyed by the reset seed), and a step is the same
C MuJoCo step, observation, reward and termination; the time limit is 1000 steps (gymnasium's ``TimeLimit``).
"""

from __future__ import annotations

import gymnasium as gym
import jax
import numpy as np

from .c_backend import Sims
from .rules import forward_position, mj_model, observe, reset_state, step_outcome
from .spec import ENVS, ON_REGISTER, env_spec

IDS: dict = {}  # (env, dynamics) -> gymnasium id, for every env known (register_gym_envs)


class MinSubDTEnv(gym.Env):
    """``env`` (hopper, walker, halfcheetah) in ``dynamics`` (brax, d4rl), stepped in C MuJoCo."""

    metadata = {"render_modes": []}

    def __init__(self, env: str = "hopper", dynamics: str = "brax"):
        spec = env_spec(env)
        self.env_name, self.dynamics = spec.name, dynamics
        self.sims = Sims(spec.name, dynamics, 1, threads=1)
        self.rules = self.sims.rules
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (spec.obs_dim,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (spec.act_dim,), np.float32)
        self._key = jax.random.PRNGKey(0)

    def _obs(self):
        return observe(self.rules, np.array(self.sims.qpos), np.array(self.sims.qvel), self.sims.torso(),
                       np).astype(np.float32)[0]

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        if seed is not None:
            self._key = jax.random.PRNGKey(seed)
        self._key, key = jax.random.split(self._key)
        qpos, qvel = reset_state(self.rules, mj_model(self.env_name, self.dynamics).qpos0, key)
        self.sims.set_state(np.asarray(qpos, np.float64)[None], np.asarray(qvel, np.float64)[None])
        return self._obs(), {}

    def step(self, action):
        action = np.clip(np.asarray(action, np.float64).reshape(1, -1), -1.0, 1.0)
        x_before = forward_position(self.rules, np.array(self.sims.qpos), self.sims.torso())
        self.sims.step(action)
        reward, done = step_outcome(self.rules, x_before, np.array(self.sims.qpos), np.array(self.sims.qvel),
                                    self.sims.torso(), action, np)
        return self._obs(), float(reward[0]), bool(done[0]), False, {}


def register_gym_envs() -> None:
    """Every env of :data:`~minsubdt_jax.envs.spec.ENVS` in each of its dynamics as a gymnasium id
    (``minsubdt/<Env>-<dynamics>-v0``): at import, and again for an env registered later (``envs.register_env``)."""
    for env, spec in ENVS.items():
        for dyn in spec.dynamics:
            IDS[(env, dyn)] = gym_id = f"minsubdt/{env.capitalize()}-{dyn}-v0"
            if gym_id not in gym.registry:
                gym.register(gym_id, entry_point="minsubdt_jax.envs.gym_env:MinSubDTEnv",
                             kwargs={"env": env, "dynamics": dyn}, max_episode_steps=1000)


register_gym_envs()
ON_REGISTER.append(register_gym_envs)
