"""A new environment from one file: gymnasium's Swimmer (v4 rules) as an :class:`~minsubdt_jax.envs.EnvSpec`.

    from swimmer_env import SWIMMER
    minsubdt_jax.envs.register_env(SWIMMER)      # then env="swimmer" records, trains and evaluates

The rules are gymnasium's ``Swimmer-v4`` (``envs/mujoco/swimmer_v4.py``): frame skip 4, forward reward the
x-velocity of ``qpos[0]``, control cost 1e-4 ``|a|^2``, reset noise U(±0.1) on ``qpos`` and ``qvel``, no
termination, the observation ``qpos[2:]`` then ``qvel`` (8 entries; the x-velocity is entry 3, the two joints'
speeds entries 6 and 7). brax has no swimmer, so both dynamics names run gym's XML and rules (our recordings use the
``brax`` entry). A body that swims in the floor's plane: its observation leaves out x and y (``obs_skip=2``), and it
has no height and no pitch (``z_velocity_index`` and ``pitch_index`` None).

The reference returns are this file's scale for a normalised score, not a benchmark's: random, 0.51, the mean return
of uniformly random actions over 1000 steps (200 episodes, std 10.7: ``behavior.snapshots.measure_return("swimmer",
None, 200, 1000, physics="mujoco")`` once registered); expert, 360, about what published SAC and TD3 runs reach on
Swimmer-v4.
"""

from minsubdt_jax.envs import Dynamics, EnvSpec

_GYM_SWIMMER = Dynamics("gymnasium:envs/mujoco/assets/swimmer.xml", frame_skip=4, ctrl_cost=1e-4, reset_noise=0.1,
                        obs_skip=2)
_REFERENCES = (0.51, 360.0, "tests/swimmer_env.py: random measured, expert a round figure of published runs")

SWIMMER = EnvSpec("swimmer", obs_dim=8, act_dim=2, x_velocity_index=3, z_velocity_index=None, pitch_index=None,
                  joint_velocity_start=6, reset_obs0=0.0, terminates=False, speed_hi=0.5, joint_speed_hi=10.0,
                  speed_band=(0.2, 0.3), speed_band_sat=0.2, replay_transitions=100_000,
                  dynamics={"brax": _GYM_SWIMMER, "d4rl": _GYM_SWIMMER},
                  references={"brax": _REFERENCES, "d4rl": _REFERENCES})
