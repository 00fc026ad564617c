"""PyTorch CPU reference of the two model updates, for the benchmark only (not used by training).

The same networks, losses and optimiser as :mod:`cfm_jax.learning.algorithm` (float32, Adam 1e-3,
minibatches drawn uniformly with replacement): :class:`ForwardUpdate`, the PETS ensemble as
batched matrix products over a member axis (``torch.baddbmm``, the fast way in PyTorch), and
:class:`ControllerUpdate`, the controller trained with the joint loss
``|f(s, g) - s*|^2 + |f(s, g) - s_a|^2`` through the frozen ensemble's mean. ``step()`` runs
one update on NumPy inputs. Needs torch (``pip install "cfm_jax[bench]"``, the CPU build).
"""

from __future__ import annotations

import numpy as np


def _torch(threads: int | None):
    import torch

    if threads is not None:
        torch.set_num_threads(threads)
    return torch


def _linear_stack(torch, sizes, members, generator):
    """Weights ``(members, in, out)`` and biases ``(members, 1, out)`` (LeCun-normal-like)."""
    params = []
    for fan_in, fan_out in zip(sizes[:-1], sizes[1:], strict=True):
        shape = (members, fan_in, fan_out) if members else (fan_in, fan_out)
        w = torch.randn(shape, generator=generator) / np.sqrt(fan_in)
        b = torch.zeros((members, 1, fan_out) if members else (fan_out,))
        params += [w.requires_grad_(), b.requires_grad_()]
    return params


class ForwardUpdate:
    """One Adam step of the forward ensemble on ``(state, action, observed)`` rows (inputs
    normalised by the data's statistics, standard deviations floored at 1e-3; torques by
    ``torque_limit``).

    Args:
      data: NumPy arrays ``state (n, state_dim)``, ``action (n, nv)``, ``observed (n, nv)``,
        ``torque_limit (nv,)``.
      hidden: hidden layer sizes of each member.
      members: ensemble size ``E``.
      batch_size: rows per member per step.
      threads: ``torch.set_num_threads`` (process-wide); None: leave it.
      seed: seed of the initial weights and the minibatches.

    Examples:
      >>> import numpy as np
      >>> rng = np.random.default_rng(0)
      >>> data = dict(state=rng.normal(size=(64, 4)), action=rng.normal(size=(64, 2)),
      ...             observed=rng.normal(size=(64, 2)), desired=rng.normal(size=(64, 2)),
      ...             torque_limit=np.array([20.0, 10.0]))
      >>> forward = ForwardUpdate(data, hidden=(32, 32), members=2, batch_size=16)
      >>> isinstance(forward.step(), float)  # the step's loss
      True
    """

    def __init__(
        self,
        data: dict,
        hidden=(400, 400, 400),
        members: int = 3,
        batch_size: int = 256,
        threads: int | None = None,
        seed: int = 0,
    ):
        torch = self.torch = _torch(threads)
        gen = torch.Generator().manual_seed(seed)
        self.state = torch.as_tensor(np.array(data["state"], np.float32))
        self.action = torch.as_tensor(np.array(data["action"], np.float32))
        self.observed = torch.as_tensor(np.array(data["observed"], np.float32))
        nv = self.action.shape[1]
        self.state_mean, self.state_std = self.state.mean(0), self.state.std(0).clamp_min(1e-3)
        self.accel_mean = self.observed.mean(0)
        self.accel_std = self.observed.std(0).clamp_min(1e-3)
        self.limit = torch.as_tensor(np.array(data["torque_limit"], np.float32))
        sizes = (self.state.shape[1] + nv, *hidden, 2 * nv)
        self.layers = _linear_stack(torch, sizes, members, gen)
        self.max_lv = torch.full((nv,), 0.5, requires_grad=True)
        self.min_lv = torch.full((nv,), -10.0, requires_grad=True)
        self.optimizer = torch.optim.Adam([*self.layers, self.max_lv, self.min_lv], lr=1e-3)
        self.members, self.batch_size, self.gen, self.nv = members, batch_size, gen, nv

    def predict(self, x):
        """``x (members, batch, in)`` -> mean, log-variance ``(members, batch, nv)``."""
        torch = self.torch
        for i in range(0, len(self.layers) - 2, 2):
            x = torch.relu(torch.baddbmm(self.layers[i + 1], x, self.layers[i]))
        out = torch.baddbmm(self.layers[-1], x, self.layers[-2])
        mean, raw = out[..., : self.nv], out[..., self.nv :]
        lv = self.max_lv - torch.nn.functional.softplus(self.max_lv - raw)
        lv = self.min_lv + torch.nn.functional.softplus(lv - self.min_lv)
        return mean, lv

    def inputs(self, state, tau):
        s = (state - self.state_mean) / self.state_std
        return self.torch.cat([s, tau / self.limit], -1)

    def step(self) -> float:
        torch = self.torch
        rows = torch.randint(
            0, self.state.shape[0], (self.members, self.batch_size), generator=self.gen
        )
        x = self.inputs(self.state[rows], self.action[rows])
        target = (self.observed[rows] - self.accel_mean) / self.accel_std
        mean, lv = self.predict(x)
        nll = ((target - mean) ** 2 * torch.exp(-lv) + lv).sum(-1).mean()
        loss = nll + 0.01 * (self.max_lv.sum() - self.min_lv.sum())
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return float(loss.detach())


class ControllerUpdate:
    """One Adam step of the controller with the joint loss through ``forward``'s frozen ensemble.

    Args:
      forward: the :class:`ForwardUpdate` whose ensemble mean is the model (its data,
        statistics and torch are used; building this freezes its parameters).
      data: a dict with ``desired (n, nv)``, the desired accelerations of ``forward``'s rows.
      hidden: hidden layer sizes of the controller.
      batch_size: rows per step.
      seed: seed of the initial weights and the minibatches.

    Examples:
      >>> import numpy as np
      >>> rng = np.random.default_rng(0)
      >>> data = dict(state=rng.normal(size=(64, 4)), action=rng.normal(size=(64, 2)),
      ...             observed=rng.normal(size=(64, 2)), desired=rng.normal(size=(64, 2)),
      ...             torque_limit=np.array([20.0, 10.0]))
      >>> forward = ForwardUpdate(data, hidden=(32, 32), members=2, batch_size=16)
      >>> controller = ControllerUpdate(forward, data, hidden=(32,), batch_size=16)
      >>> controller.step() > 0  # the joint loss, a sum of squares
      True
    """

    def __init__(
        self,
        forward: ForwardUpdate,
        data: dict,
        hidden=(300, 200, 100),
        batch_size: int = 256,
        seed: int = 1,
    ):
        torch = self.torch = forward.torch
        gen = torch.Generator().manual_seed(seed)
        self.forward = forward
        for p in [*forward.layers, forward.max_lv, forward.min_lv]:
            p.requires_grad_(False)
        self.desired = torch.as_tensor(np.array(data["desired"], np.float32))
        nv = forward.nv
        sizes = (forward.state.shape[1] + nv, *hidden, nv)
        self.layers = _linear_stack(torch, sizes, 0, gen)
        self.optimizer = torch.optim.Adam(self.layers, lr=1e-3)
        self.batch_size, self.gen = batch_size, gen

    def step(self) -> float:
        torch, f = self.torch, self.forward
        rows = torch.randint(0, f.state.shape[0], (self.batch_size,), generator=self.gen)
        state, desired, observed = f.state[rows], self.desired[rows], f.observed[rows]
        desired_n = (desired - f.accel_mean) / f.accel_std
        observed_n = (observed - f.accel_mean) / f.accel_std
        x = torch.cat([(state - f.state_mean) / f.state_std, desired_n], -1)
        for i in range(0, len(self.layers) - 2, 2):
            x = torch.relu(torch.addmm(self.layers[i + 1], x, self.layers[i]))
        tau = f.limit * torch.tanh(torch.addmm(self.layers[-1], x, self.layers[-2]))
        inputs = f.inputs(state, tau).expand(f.members, -1, -1)
        predicted = f.predict(inputs)[0].mean(0)
        loss = (
            ((predicted - desired_n) ** 2).sum(-1) + ((predicted - observed_n) ** 2).sum(-1)
        ).mean()
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return float(loss.detach())
