"""A short, self-contained PPO for continuous actions over a gymnasium ``VectorEnv``, in NumPy only.

What it is: proximal policy optimisation (Schulman et al. 2017, "Proximal Policy Optimization
Algorithms", arXiv:1707.06347) with generalised advantage estimation (Schulman et al. 2016,
arXiv:1506.02438), written after cleanrl's ``ppo_continuous_action.py`` (Huang et al. 2022,
"The 37 Implementation Details of PPO") whose hyperparameters are :class:`PPOConfig`'s defaults:
separate policy and value MLPs (2 x 64 tanh, orthogonal init), a state-independent log-std, observation
normalisation and reward scaling (gymnasium's ``NormalizeObservation`` / ``NormalizeReward``, clipped
to +-10), per-minibatch advantage normalisation, clipped value loss, Adam (eps 1e-5) with a linearly
annealed learning rate and the global gradient norm clipped to 0.5. Forward and backward passes are
written out by hand in float64 (:func:`gradient_check` compares them with finite differences), so
training needs no deep-learning framework: the policy runs on the host, the environment wherever it
steps.

How to use::

    from physhand_dmc.ppo import Agent, PPOConfig, train
    agent = Agent(obs_dim, act_dim, seed=0)
    history = train(env, total_steps=100_000, seed=0, agent=agent, log=print)
    action = agent.act(obs, deterministic=True)        # obs: (num_envs, obs_dim) raw observations

The environment: a ``gymnasium.vector.VectorEnv`` (or anything with its ``reset`` / ``step``
signatures, ``single_observation_space`` / ``single_action_space`` Boxes, ``num_envs`` and
``metadata["autoreset_mode"]``) with flat Box observations (num_envs, obs_dim). Sampled actions are
clipped to the action space before stepping; the unclipped sample is what the log-probabilities use.
Autoreset modes: NEXT_STEP (gymnasium's default: the step after an episode ends resets that env, and
that transition is masked out of the loss) and SAME_STEP (the true final observation, from
``info["final_obs"]``, bootstraps truncated episodes). DISABLED is refused.

Current figures (2-core AMD EPYC, default PPOConfig): the optimisation phase takes 0.11 s for a
2,048-step batch, 0.3 s for 16,384 and 2 s for 65,536 (1,024 / 4,096 envs x 16 steps; obs 2-D);
Pendulum-v1 with 8 envs runs at 11,500-14,000 env steps/s overall and goes from about -1,200 to
about -150 mean episode return within 100k-150k env steps (1M steps: 87 s, level at -100 to -200).

Known limits: one process, host NumPy (device arrays from the env are copied to the host each
step); flat Box spaces only; no recurrent policies.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

LOG_2PI = np.log(2.0 * np.pi)


@dataclass
class PPOConfig:
    """PPO's hyperparameters; defaults are cleanrl's ``ppo_continuous_action.py`` (one env there)."""

    num_steps: int = 2048          # env steps per env per rollout; batch = num_steps * num_envs
    learning_rate: float = 3e-4    # Adam's step size at update 1
    anneal_lr: bool = True         # learning rate linearly to 0 over the run
    gamma: float = 0.99            # discount per env step
    gae_lambda: float = 0.95       # GAE's lambda
    num_minibatches: int = 32      # per epoch
    update_epochs: int = 10        # passes over each rollout
    norm_adv: bool = True          # advantages to zero mean, unit std per minibatch
    clip_coef: float = 0.2         # surrogate's ratio clip (and the value clip when clip_vloss)
    clip_vloss: bool = True        # clipped value loss
    ent_coef: float = 0.0          # entropy bonus
    vf_coef: float = 0.5           # value loss weight
    max_grad_norm: float = 0.5     # global gradient norm clip (both networks together)
    target_kl: float | None = None  # stop an update's epochs once approx KL exceeds this
    norm_obs: bool = True          # running mean/var observation normalisation, clipped to +-10
    norm_reward: bool = True       # rewards divided by the discounted return's running std, clipped to +-10
    hidden: int = 64               # width of both hidden layers of both networks


# train()'s record per update (the columns of examples/train_ppo.py's history.csv)
HISTORY_FIELDS = ("update", "global_step", "episode_return", "episode_length", "episodes", "reward_mean",
                  "policy_loss", "value_loss", "entropy", "approx_kl", "clipfrac", "explained_variance",
                  "learning_rate", "grad_norm", "sps", "update_s", "wall_s")


class RunningMeanStd:
    """Running mean and variance of a batch stream (Chan et al.'s parallel update, as gymnasium's)."""

    def __init__(self, shape=(), epsilon: float = 1e-4):
        self.mean, self.var, self.count = np.zeros(shape), np.ones(shape), epsilon

    def update(self, x: np.ndarray) -> None:
        """x: (batch, *shape)."""
        b_mean, b_var, b_count = x.mean(0), x.var(0), x.shape[0]
        delta, total = b_mean - self.mean, self.count + b_count
        self.mean = self.mean + delta * b_count / total
        self.var = (self.var * self.count + b_var * b_count + delta**2 * self.count * b_count / total) / total
        self.count = total


def _orthogonal(rng: np.random.Generator, n_in: int, n_out: int, gain: float) -> np.ndarray:
    """An (n_in, n_out) matrix with orthonormal rows or columns times gain (torch's orthogonal_)."""
    q, r = np.linalg.qr(rng.standard_normal((max(n_in, n_out), min(n_in, n_out))))
    q = q * np.sign(np.diag(r))
    return gain * (q if n_in >= n_out else q.T)


class MLP:
    """x (B, n_in) -> tanh -> tanh -> linear (B, n_out); params [W1, b1, W2, b2, W3, b3], W: (in, out)."""

    def __init__(self, sizes: list[int], rng: np.random.Generator, out_gain: float):
        gains = [np.sqrt(2.0)] * (len(sizes) - 2) + [out_gain]
        self.params = []
        for n_in, n_out, g in zip(sizes[:-1], sizes[1:], gains):
            self.params += [_orthogonal(rng, n_in, n_out, g), np.zeros(n_out)]

    def forward(self, x: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        """Returns the output and the cache of each layer's input for :meth:`backward`."""
        cache, n = [x], len(self.params) // 2
        for k in range(n):
            x = x @ self.params[2 * k] + self.params[2 * k + 1]
            if k < n - 1:
                x = np.tanh(x)
                cache.append(x)
        return x, cache

    def backward(self, cache: list[np.ndarray], dy: np.ndarray) -> list[np.ndarray]:
        """dy: d loss / d output (B, n_out) -> d loss / d params, in params' order."""
        grads = [None] * len(self.params)
        for k in reversed(range(len(self.params) // 2)):
            x = cache[k]
            grads[2 * k], grads[2 * k + 1] = x.T @ dy, dy.sum(0)
            if k > 0:
                dy = (dy @ self.params[2 * k].T) * (1.0 - x * x)  # x = tanh(.) of the layer below
        return grads


class Agent:
    """Gaussian policy (mean MLP + state-independent log-std) and value MLP; obs normaliser.

    ``params`` = policy MLP's 6 arrays, log_std (act_dim,), value MLP's 6 arrays (13 arrays, all
    updated in place by the optimiser).
    """

    def __init__(self, obs_dim: int, act_dim: int, seed: int = 0, hidden: int = 64):
        rng = np.random.default_rng(seed)
        self.pi = MLP([obs_dim, hidden, hidden, act_dim], rng, out_gain=0.01)
        self.vf = MLP([obs_dim, hidden, hidden, 1], rng, out_gain=1.0)
        self.log_std = np.zeros(act_dim)
        self.obs_rms = RunningMeanStd((obs_dim,))
        self.norm_obs = True

    @property
    def params(self) -> list[np.ndarray]:
        return [*self.pi.params, self.log_std, *self.vf.params]

    def normalize(self, obs: np.ndarray, update: bool = False) -> np.ndarray:
        """Raw (B, obs_dim) -> normalised float64, clipped to +-10 (identity when norm_obs is off)."""
        obs = np.asarray(obs, dtype=np.float64)
        if not self.norm_obs:
            return obs
        if update:
            self.obs_rms.update(obs)
        return np.clip((obs - self.obs_rms.mean) / np.sqrt(self.obs_rms.var + 1e-8), -10.0, 10.0)

    def value(self, obs_n: np.ndarray) -> np.ndarray:
        """Normalised obs (B, obs_dim) -> V (B,)."""
        return self.vf.forward(obs_n)[0][:, 0]

    def act(self, obs: np.ndarray, rng: np.random.Generator | None = None, deterministic: bool = False):
        """Raw obs (B, obs_dim) -> unclipped actions (B, act_dim): the mean, or a sample from rng."""
        mean = self.pi.forward(self.normalize(obs))[0]
        if deterministic:
            return mean
        return mean + np.exp(self.log_std) * (rng or np.random.default_rng()).standard_normal(mean.shape)

    def save(self, path) -> None:
        """An .npz of params (arr_0 ... arr_12, in params' order), obs_mean, obs_var, obs_count."""
        np.savez(path, *self.params, obs_mean=self.obs_rms.mean, obs_var=self.obs_rms.var,
                 obs_count=self.obs_rms.count, norm_obs=self.norm_obs)

    @classmethod
    def load(cls, path) -> Agent:
        """The agent :meth:`save` wrote."""
        z = np.load(path)
        params = [z[f"arr_{i}"] for i in range(13)]
        agent = cls(params[0].shape[0], params[6].shape[0], hidden=params[0].shape[1])
        for p, q in zip(agent.params, params):
            p[...] = q
        agent.obs_rms.mean, agent.obs_rms.var, agent.obs_rms.count = z["obs_mean"], z["obs_var"], float(z["obs_count"])
        agent.norm_obs = bool(z["norm_obs"])
        return agent


def log_prob(mean: np.ndarray, log_std: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """Diagonal Gaussian log-density of actions (B, act_dim) -> (B,)."""
    z = (actions - mean) / np.exp(log_std)
    return (-0.5 * z * z - log_std - 0.5 * LOG_2PI).sum(1)


def policy_loss(agent: Agent, obs_n, actions, old_logp, adv, clip_coef: float, ent_coef: float):
    """Clipped surrogate minus the entropy bonus (Schulman et al. 2017, eq. 7) and its gradient.

    obs_n (B, obs_dim) normalised, actions (B, act_dim) unclipped samples, old_logp (B,), adv (B,)
    (already normalised if wanted). Returns (loss, [d/d pi params..., d/d log_std], stats).
    """
    mean, cache = agent.pi.forward(obs_n)
    std = np.exp(agent.log_std)
    logratio = log_prob(mean, agent.log_std, actions) - old_logp
    ratio = np.exp(logratio)
    clipped = np.clip(ratio, 1.0 - clip_coef, 1.0 + clip_coef)
    unclipped_loss, clipped_loss = -adv * ratio, -adv * clipped
    entropy = (0.5 + 0.5 * LOG_2PI + agent.log_std).sum()
    loss = np.maximum(unclipped_loss, clipped_loss).mean() - ent_coef * entropy
    # d max(u, c) / d ratio: the unclipped branch where it is the max, else clip's slope (0 outside)
    inside = (ratio > 1.0 - clip_coef) & (ratio < 1.0 + clip_coef)
    d_logp = -adv * ratio * np.where(unclipped_loss >= clipped_loss, 1.0, inside) / len(adv)
    z = (actions - mean) / std
    d_mean = d_logp[:, None] * z / std                      # d logp / d mean = (a - mu) / sigma^2
    d_log_std = (d_logp[:, None] * (z * z - 1.0)).sum(0) - ent_coef
    stats = {"approx_kl": float(((ratio - 1.0) - logratio).mean()),  # Schulman's k3 estimator
                 "clipfrac": float((np.abs(ratio - 1.0) > clip_coef).mean()), "entropy": float(entropy)}
    return float(loss), [*agent.pi.backward(cache, d_mean), d_log_std], stats


def value_loss(agent: Agent, obs_n, returns, old_values, clip_coef: float | None):
    """0.5 * mean squared error to the returns, clipped around old_values when clip_coef is set.

    obs_n (B, obs_dim), returns (B,), old_values (B,). Returns (loss, d/d value params).
    """
    out, cache = agent.vf.forward(obs_n)
    v = out[:, 0]
    if clip_coef is None:
        loss, d_v = 0.5 * ((v - returns) ** 2).mean(), (v - returns) / len(v)
    else:
        dv = np.clip(v - old_values, -clip_coef, clip_coef)
        unclipped, clipped = (v - returns) ** 2, (old_values + dv - returns) ** 2
        loss = 0.5 * np.maximum(unclipped, clipped).mean()
        slope = np.where(unclipped >= clipped, v - returns, (old_values + dv - returns) * (np.abs(v - old_values) < clip_coef))
        d_v = slope / len(v)
    return float(loss), agent.vf.backward(cache, d_v[:, None])


class Adam:
    """Adam (Kingma & Ba 2015) over a list of arrays, updated in place."""

    def __init__(self, params: list[np.ndarray], lr: float, betas=(0.9, 0.999), eps: float = 1e-5):
        self.params, self.lr, self.betas, self.eps, self.t = params, lr, betas, eps, 0
        self.m = [np.zeros_like(p) for p in params]
        self.v = [np.zeros_like(p) for p in params]

    def step(self, grads: list[np.ndarray]) -> None:
        self.t += 1
        b1, b2 = self.betas
        for p, g, m, v in zip(self.params, grads, self.m, self.v):
            m *= b1
            m += (1 - b1) * g
            v *= b2
            v += (1 - b2) * g * g
            p -= self.lr * (m / (1 - b1**self.t)) / (np.sqrt(v / (1 - b2**self.t)) + self.eps)


def clip_grad_norm(grads: list[np.ndarray], max_norm: float) -> float:
    """Scales grads in place so their global L2 norm is at most max_norm; returns the norm before."""
    norm = float(np.sqrt(sum((g * g).sum() for g in grads)))
    if norm > max_norm:
        for g in grads:
            g *= max_norm / (norm + 1e-6)
    return norm


def finite_difference_error(fn, params: list[np.ndarray], h: float = 1e-6) -> float:
    """Largest relative error ||g - g_fd|| / (||g|| + ||g_fd||) over params' arrays.

    fn() -> (loss, grads) reads params (modified in place here, restored after); g_fd by central
    differences of step h in every entry.
    """
    _, grads = fn()
    worst = 0.0
    for p, g in zip(params, grads):
        g_fd = np.zeros_like(p)
        for i in np.ndindex(p.shape):
            keep = p[i]
            p[i] = keep + h
            up = fn()[0]
            p[i] = keep - h
            down = fn()[0]
            p[i] = keep
            g_fd[i] = (up - down) / (2 * h)
        worst = max(worst, np.linalg.norm(g - g_fd) / max(np.linalg.norm(g) + np.linalg.norm(g_fd), 1e-300))
    return float(worst)


def gradient_check(seed: int = 0, batch: int = 16, corrupt: float = 0.0) -> dict[str, float]:
    """Manual backward vs finite differences on a tiny agent (obs 3, act 2, hidden 5), both losses.

    The data puts some ratios and value changes past the clip, so both branches are checked.
    corrupt: adds this relative error to the first gradient array (so a test can see the check fail).
    Returns {"policy": max relative error, "value": ...}.
    """
    rng = np.random.default_rng(seed)
    agent = Agent(3, 2, seed=seed, hidden=5)
    for p in agent.params:  # larger weights than the init, so every layer's gradient is sizeable
        p[...] = rng.standard_normal(p.shape) * 0.5
    obs, actions, adv = rng.standard_normal((batch, 3)), rng.standard_normal((batch, 2)), rng.standard_normal(batch)
    old_logp = log_prob(agent.pi.forward(obs)[0], agent.log_std, actions) + 0.4 * rng.standard_normal(batch)
    returns, old_v = rng.standard_normal(batch), agent.value(obs) + 0.3 * rng.standard_normal(batch)

    def bad(fn):
        def wrapped():
            loss, grads = fn()
            return loss, [grads[0] * (1 + corrupt), *grads[1:]]
        return wrapped

    pi_params = [*agent.pi.params, agent.log_std]
    return {
        "policy": finite_difference_error(bad(lambda: policy_loss(agent, obs, actions, old_logp, adv, 0.2, 0.01)[:2]), pi_params),
        "value": finite_difference_error(bad(lambda: value_loss(agent, obs, returns, old_v, 0.2)), agent.vf.params)}


def gae(rewards, values, next_values, terminated, ended, gamma: float, lam: float) -> np.ndarray:
    """Generalised advantage estimates (Schulman et al. 2016, eq. 16), all arrays (T, num_envs).

    next_values[t]: V of the observation step t led to (the final one where an episode ended), so a
    truncated episode bootstraps from it and a terminated one (terminated[t]) does not; ended[t]
    (terminated or truncated) stops the sum from running into the next episode.
    """
    adv, last = np.zeros_like(values), np.zeros_like(values[0])
    for t in reversed(range(len(values))):
        # (where, not a product: a terminated step's next value may be non-finite, 0 * nan = nan)
        delta = rewards[t] + gamma * np.where(terminated[t], 0.0, next_values[t]) - values[t]
        last = delta + gamma * lam * ~ended[t] * last
        adv[t] = last
    return adv


def _autoreset_mode(env) -> str:
    mode = env.metadata.get("autoreset_mode", "NextStep")
    mode = getattr(mode, "value", mode)  # gymnasium.vector.AutoresetMode or its string
    if mode not in ("NextStep", "SameStep"):
        raise ValueError(f"autoreset mode {mode!r} is not supported: make the VectorEnv with "
                         "autoreset_mode NEXT_STEP (gymnasium's default) or SAME_STEP")
    return mode


def train(env, total_steps: int, seed: int = 0, config: PPOConfig | None = None, agent: Agent | None = None,
          log=None) -> list[dict]:
    """PPO on a VectorEnv for total_steps env steps (summed over envs); trains agent in place.

    log(record) is called after each update with that update's history record. Returns the records:
    update, global_step (env steps so far), episode_return / episode_length (means over the episodes
    that ended in this rollout, undiscounted raw rewards; NaN when none ended), episodes, reward_mean
    (raw reward per env step), policy_loss, value_loss, entropy, approx_kl, clipfrac,
    explained_variance, learning_rate, grad_norm, sps (env steps per second over the update, rollout and
    optimisation), update_s (seconds in the optimisation), wall_s (seconds since start).
    """
    cfg = config or PPOConfig()
    mode = _autoreset_mode(env)
    if len(env.single_observation_space.shape) != 1 or len(env.single_action_space.shape) != 1:
        raise ValueError(f"flat Box spaces only: observations {env.single_observation_space}, "
                         f"actions {env.single_action_space} (flatten them with a wrapper)")
    n_envs = env.num_envs
    (obs_dim,), (act_dim,) = env.single_observation_space.shape, env.single_action_space.shape
    low, high = env.single_action_space.low, env.single_action_space.high
    agent = agent or Agent(obs_dim, act_dim, seed=seed, hidden=cfg.hidden)
    agent.norm_obs = cfg.norm_obs
    rng = np.random.default_rng(seed)
    opt = Adam(agent.params, cfg.learning_rate)
    T, batch = cfg.num_steps, cfg.num_steps * n_envs
    num_updates = max(1, total_steps // batch)

    obs_b = np.zeros((T, n_envs, obs_dim))
    act_b = np.zeros((T, n_envs, act_dim))
    logp_b, val_b, next_val_b, rew_b, raw_rew_b = (np.zeros((T, n_envs)) for _ in range(5))
    term_b, done_b, valid_b = (np.zeros((T, n_envs), bool) for _ in range(3))
    ret_rms, disc_ret = RunningMeanStd(), np.zeros(n_envs)
    ep_ret, ep_len = np.zeros(n_envs), np.zeros(n_envs, int)
    pending_reset = np.zeros(n_envs, bool)  # NEXT_STEP: this env's next step() is its reset
    obs, _ = env.reset(seed=seed)
    start, global_step, history = time.perf_counter(), 0, []

    for update in range(1, num_updates + 1):
        t0 = time.perf_counter()
        opt.lr = cfg.learning_rate * (1.0 - (update - 1.0) / num_updates) if cfg.anneal_lr else cfg.learning_rate
        finished = []
        # ---- rollout ----
        for t in range(T):
            o = agent.normalize(obs, update=True)
            mean = agent.pi.forward(o)[0]
            a = mean + np.exp(agent.log_std) * rng.standard_normal(mean.shape)
            obs_b[t], act_b[t], valid_b[t] = o, a, ~pending_reset
            logp_b[t], val_b[t] = log_prob(mean, agent.log_std, a), agent.value(o)
            obs, r, term, trunc, info = env.step(np.clip(a, low, high).astype(env.single_action_space.dtype))
            r, term, trunc = (np.asarray(x) for x in (r, term, trunc))
            done = (term | trunc) & valid_b[t]
            r = np.where(valid_b[t], r, 0.0)
            raw_rew_b[t], term_b[t], done_b[t] = r, term & valid_b[t], done
            if cfg.norm_reward:  # gymnasium's NormalizeReward: r / std(discounted return)
                disc_ret = disc_ret * cfg.gamma + r
                if valid_b[t].any():
                    ret_rms.update(disc_ret[valid_b[t]])
                r = np.clip(r / np.sqrt(ret_rms.var + 1e-8), -10.0, 10.0)
                disc_ret[done] = 0.0
            rew_b[t] = r
            if mode == "SameStep" and done.any():  # obs is already the reset obs: bootstrap from final_obs
                final = np.stack([np.asarray(info["final_obs"][i], dtype=np.float64) for i in np.flatnonzero(done)])
                next_val_b[t, done] = agent.value(agent.normalize(final))
            ep_ret += raw_rew_b[t]
            ep_len += valid_b[t]
            finished += [(ep_ret[i], ep_len[i]) for i in np.flatnonzero(done)]
            ep_ret[done], ep_len[done] = 0.0, 0
            if mode == "NextStep":
                pending_reset = done
        global_step += batch
        # ---- advantages; each step's value target is adv + V ----
        last_val = agent.value(agent.normalize(obs))
        next_vals = np.concatenate([val_b[1:], last_val[None]])
        if mode == "SameStep":
            next_vals = np.where(done_b, next_val_b, next_vals)
        adv = gae(rew_b, val_b, next_vals, term_b, done_b, cfg.gamma, cfg.gae_lambda)
        ret = adv + val_b
        # ---- optimise over the valid transitions (NEXT_STEP's reset steps are left out) ----
        keep = valid_b.reshape(-1)
        b_obs, b_act = obs_b.reshape(-1, obs_dim)[keep], act_b.reshape(-1, act_dim)[keep]
        b_logp, b_adv, b_ret, b_val = (x.reshape(-1)[keep] for x in (logp_b, adv, ret, val_b))
        n, mb = len(b_obs), max(1, keep.sum() // cfg.num_minibatches)
        stats, t_opt = [], time.perf_counter()
        for epoch in range(cfg.update_epochs):
            order = rng.permutation(n)
            for s in range(0, n, mb):
                i = order[s:s + mb]
                a_ = b_adv[i]
                if cfg.norm_adv and len(i) > 1:
                    a_ = (a_ - a_.mean()) / (a_.std() + 1e-8)
                pl, pg, st = policy_loss(agent, b_obs[i], b_act[i], b_logp[i], a_, cfg.clip_coef, cfg.ent_coef)
                vl, vg = value_loss(agent, b_obs[i], b_ret[i], b_val[i], cfg.clip_coef if cfg.clip_vloss else None)
                grads = [*pg, *(g * cfg.vf_coef for g in vg)]
                gn = clip_grad_norm(grads, cfg.max_grad_norm)
                opt.step(grads)
                stats.append(dict(policy_loss=pl, value_loss=vl, grad_norm=gn, **st))
            if cfg.target_kl is not None and stats[-1]["approx_kl"] > cfg.target_kl:
                break
        var_y = b_ret.var()
        rec = dict(update=update, global_step=global_step,
                   episode_return=float(np.mean([f[0] for f in finished])) if finished else float("nan"),
                   episode_length=float(np.mean([f[1] for f in finished])) if finished else float("nan"),
                   episodes=len(finished), reward_mean=float(raw_rew_b[valid_b].mean()),
                   **{k: float(np.mean([s[k] for s in stats])) for k in stats[0]},
                   explained_variance=float(1 - (b_ret - b_val).var() / var_y) if var_y > 0 else float("nan"),
                   learning_rate=opt.lr, sps=batch / (time.perf_counter() - t0),
                   update_s=time.perf_counter() - t_opt,
                   wall_s=time.perf_counter() - start)
        history.append(rec)
        if log is not None:
            log(rec)
    return history
