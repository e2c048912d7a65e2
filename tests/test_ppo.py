"""physhand_dmc.ppo: the manual backward against finite differences, GAE by hand, value targets
across truncations and autoresets (both modes), updates on a gymnasium vector env, and learning
(a 1-D reach, both modes; Pendulum-v1 in the slow set). CPU, NumPy only: ~6 s, Pendulum 11 s more."""

import math

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

from physhand_dmc import ppo

GRAD_RTOL = 1e-5  # central differences (h = 1e-6) in float64 agree to ~1e-9 when the backward is right


class Reach1D(gym.vector.VectorEnv):
    """W points on a line, each to reach its target: x += STEP * a (a in [-1, 1]), reward -|x - target|,
    terminated within TOL of the target, truncated after LIMIT steps; obs [x, target] in [-1, 1].

    A random policy scores about -19 per episode; PPO reaches about -1.5 in 40 updates (the test prints both)."""

    STEP, TOL, LIMIT = 0.2, 0.05, 30

    def __init__(self, num_envs: int = 8, autoreset_mode: str = "NextStep"):
        self.num_envs = num_envs
        self.single_observation_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, num_envs)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, num_envs)
        self.metadata = {"autoreset_mode": gym.vector.AutoresetMode(autoreset_mode)}
        self.mode = autoreset_mode

    def _obs(self):
        return np.stack([self.x, self.target], 1).astype(np.float32)

    def _reset(self, mask):
        self.x[mask] = self.rng.uniform(-1, 1, mask.sum())
        self.target[mask] = self.rng.uniform(-1, 1, mask.sum())
        self.t[mask] = 0

    def reset(self, *, seed=None, options=None):
        self.rng = np.random.default_rng(seed)
        self.x, self.target, self.t = np.zeros(self.num_envs), np.zeros(self.num_envs), np.zeros(self.num_envs, int)
        self.ended = np.zeros(self.num_envs, bool)
        self._reset(np.ones(self.num_envs, bool))
        return self._obs(), {}

    def step(self, actions):
        assert actions.shape == (self.num_envs, 1) and np.all(np.abs(actions) <= 1), "actions must be clipped"
        restart = self.ended.copy()  # NEXT_STEP: this step resets the envs that ended last step
        self.x = np.clip(self.x + self.STEP * actions[:, 0], -1, 1)
        self.t += 1
        dist = np.abs(self.x - self.target)
        reward, term, trunc = -dist, dist < self.TOL, self.t >= self.LIMIT
        info = {}
        if self.mode == "NextStep":
            self._reset(restart)
            reward[restart], term[restart], trunc[restart] = 0.0, False, False
            self.ended = term | trunc
            return self._obs(), reward, term, trunc, info
        done = term | trunc
        if done.any():
            final = np.empty(self.num_envs, object)
            for i in np.flatnonzero(done):
                final[i] = self._obs()[i]
            info = {"final_obs": final, "_final_obs": done}
            self._reset(done)
        return self._obs(), reward, term, trunc, info


class Tick(Reach1D):
    """Observation [1, c], reward 1 + c every step, c = +1 and -1 in alternate episodes, truncated
    every LIMIT steps, never terminated: bootstrapping each truncation from its final observation,
    V = (1 + c) / (1 - gamma), i.e. 4 and 0 for gamma = 0.5."""

    LIMIT = 3

    def _obs(self):
        return np.stack([np.ones(self.num_envs), self.c], 1).astype(np.float32)

    def step(self, actions):
        c = self.c.copy()
        obs, _, _, trunc, info = super().step(actions)  # Reach1D's clock and autoreset, Tick's reward
        reward = 1.0 + c
        if self.mode == "NextStep":
            reward[self.t == 0] = 0.0  # gymnasium's convention for the reset step (which PPO must drop)
        return obs, reward, np.zeros(self.num_envs, bool), trunc, info

    def reset(self, *, seed=None, options=None):
        self.c = -np.ones(self.num_envs)  # the first episodes have c = +1
        return super().reset(seed=seed, options=options)

    def _reset(self, mask):
        super()._reset(mask)
        self.target[:] = 10.0  # out of reach: no terminations
        self.c[mask] *= -1


@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_value_bootstraps_truncations_from_the_final_obs_and_skips_reset_steps(mode):
    """Bootstrapping from the next episode's first observation, or keeping NEXT_STEP's reward-0 reset
    steps, moves V(c = +1) well below 4."""
    cfg = ppo.PPOConfig(num_steps=32, num_minibatches=2, update_epochs=10, gamma=0.5, learning_rate=1e-2,
                        clip_vloss=False, norm_obs=False, norm_reward=False)
    agent = ppo.Agent(2, 1, seed=0)
    ppo.train(Tick(num_envs=4, autoreset_mode=mode), total_steps=60 * 32 * 4, seed=0, config=cfg, agent=agent)
    v = agent.value(np.array([[1.0, 1.0], [1.0, -1.0]]))
    np.testing.assert_allclose(v, [4.0, 0.0], atol=0.05)


def test_manual_backward_matches_finite_differences():
    errs = ppo.gradient_check(seed=0)
    assert errs["policy"] < GRAD_RTOL and errs["value"] < GRAD_RTOL, errs
    # a gradient 0.1 % off in one array fails the check by 50x (so it is not vacuous)
    bad = ppo.gradient_check(seed=0, corrupt=1e-3)
    assert bad["policy"] > 10 * GRAD_RTOL and bad["value"] > 10 * GRAD_RTOL, bad


def test_gae_bootstraps_truncations_not_terminations_and_stops_at_episode_ends():
    g, lam = 0.9, 0.5
    r, v, nv = np.array([[1.0], [2.0], [3.0]]), np.array([[0.5], [0.25], [0.125]]), np.array([[0.25], [7.0], [4.0]])
    ended = np.array([[False], [True], [False]])
    for terminated in (False, True):  # step 1 ends its episode: truncated (bootstraps V = 7) or terminated
        term = np.array([[False], [terminated], [False]])
        adv = ppo.gae(r, v, nv, term, ended, g, lam)
        a2 = 3.0 + g * 4.0 - 0.125                              # the next episode's step: unaffected
        a1 = 2.0 + (0.0 if terminated else g * 7.0) - 0.25      # not summed into from step 2
        a0 = 1.0 + g * 0.25 - 0.5 + g * lam * a1
        np.testing.assert_allclose(adv[:, 0], [a0, a1, a2], rtol=1e-12)


def test_updates_on_a_gymnasium_vector_env(tmp_path):
    env = gym.make_vec("Pendulum-v1", num_envs=4, vectorization_mode="sync")
    agent = ppo.Agent(3, 1, seed=0)
    before = [p.copy() for p in agent.params]
    cfg = ppo.PPOConfig(num_steps=64, num_minibatches=4, update_epochs=2)
    seen = []
    history = ppo.train(env, total_steps=4 * 64 * 4, seed=0, config=cfg, agent=agent, log=seen.append)
    env.close()
    assert len(history) == 4 and seen == history
    for rec in history:
        assert set(ppo.HISTORY_FIELDS) == set(rec), sorted(rec)
        for k in ("policy_loss", "value_loss", "entropy", "approx_kl", "reward_mean", "grad_norm"):
            assert math.isfinite(rec[k]), (k, rec)
    assert [r["global_step"] for r in history] == [256, 512, 768, 1024]
    changed = [not np.array_equal(a, b) for a, b in zip(before, agent.params)]
    assert all(changed), changed
    obs = np.random.default_rng(0).standard_normal((5, 3))
    agent.save(tmp_path / "agent.npz")
    again = ppo.Agent.load(tmp_path / "agent.npz")
    np.testing.assert_array_equal(again.act(obs, deterministic=True), agent.act(obs, deterministic=True))
    # Pendulum truncates at 200 steps: each env's first episode ends in update 4 (NEXT_STEP masks their reset steps)
    assert history[-1]["episodes"] == 4 and history[-1]["episode_length"] == 200, history[-1]


def _random_return(env, episodes_wanted=64, seed=1):
    rng, returns, ep = np.random.default_rng(seed), [], np.zeros(env.num_envs)
    env.reset(seed=seed)
    while len(returns) < episodes_wanted:
        _, r, term, trunc, _ = env.step(rng.uniform(-1, 1, (env.num_envs, 1)))
        ep += r
        for i in np.flatnonzero(term | trunc):
            returns.append(ep[i])
            ep[i] = 0.0
    return float(np.mean(returns))


@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_learns_to_reach(mode):
    env = Reach1D(num_envs=8, autoreset_mode=mode)
    random_return = _random_return(Reach1D(num_envs=8, autoreset_mode="SameStep"))
    cfg = ppo.PPOConfig(num_steps=128, num_minibatches=8, update_epochs=10)
    history = ppo.train(env, total_steps=40 * 128 * 8, seed=0, config=cfg)
    first = np.nanmean([h["episode_return"] for h in history[:2]])
    last = np.nanmean([h["episode_return"] for h in history[-3:]])
    print(f"{mode}: random {random_return:.1f}, first updates {first:.1f}, last updates {last:.1f}, "
          f"{history[-1]['wall_s']:.1f} s")
    # the cost (a negative return) at least halves from the random policy's and from the first updates'
    assert last > 0.5 * random_return and last > 0.5 * first, (random_return, first, last)


@pytest.mark.slow
def test_learns_pendulum():
    """cleanrl's defaults on Pendulum-v1: about -1,200 at first, about -150 after 100k-150k env steps
    (8 envs; 9 s on a 2-core CPU; 1M steps level off at -100 to -200)."""
    env = gym.make_vec("Pendulum-v1", num_envs=8, vectorization_mode="sync")
    cfg = ppo.PPOConfig(num_steps=256)
    history = ppo.train(env, total_steps=150_000, seed=0, config=cfg)
    env.close()
    first = np.nanmean([h["episode_return"] for h in history[:8]])
    last = np.nanmean([h["episode_return"] for h in history[-8:]])
    print(f"Pendulum: first updates {first:.0f}, last updates {last:.0f}, {history[-1]['wall_s']:.1f} s")
    assert last > 0.5 * first, (first, last)  # the cost at least halves (it falls ~5x when learning works)
