"""The thesis's Q-network (Model §2, Fig. 13) and the observation transform that feeds it.

The network maps a ``(N, C, k, k)`` potential window to nine action values:
2×2 convolutions, each of the first two followed by a 2×2 max-pool with stride 1, then
fully connected layers 32 → 32 → 9, Leaky ReLU (λ = 0.001) between layers and no
activation on the output.

The observation transform is part of the module, so a saved network accepts the raw
observations of the environment and nobody has to remember how it was trained.
"""

from __future__ import annotations

from typing import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from apf_physics.common.transforms import signed_log

OBS_TRANSFORMS = ("raw", "relative-log", "relative-log-memory", "relative-log-previous")
"""Names accepted by :class:`QNetwork`'s ``obs_transform``."""


class _MaxPool2x2Stride1(torch.autograd.Function):
    """Separable max over shifted views (columns, then rows), with a mask-based backward.

    The forward takes the max of horizontal neighbours, then of vertical neighbours. The
    backward undoes the two steps with one comparison each: a window's gradient goes to
    the upper row when its maximum is there (ties: upper), then to the left column when
    the maximum of that row pair is there (ties: left). That is the first maximum in
    row-major order, where ``max_pool2d`` sends it, so ties are handled the same way.
    Measured ~2× cheaper than testing each of the four window positions for equality
    with the output (the previous backward) and several times cheaper than autograd
    through ``max_pool2d`` itself.
    """

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        cols = torch.maximum(x[..., :-1], x[..., 1:])
        y = torch.maximum(cols[..., :-1, :], cols[..., 1:, :])
        ctx.save_for_backward(x, cols)
        return y

    @staticmethod
    def backward(ctx, grad_y: torch.Tensor) -> torch.Tensor:
        x, cols = ctx.saved_tensors
        # rows: the upper row's column max wins ties
        upper = grad_y * (cols[..., :-1, :] >= cols[..., 1:, :]).to(grad_y.dtype)
        grad_cols = grad_y.new_empty(cols.shape)
        grad_cols[..., :-1, :] = upper
        grad_cols[..., -1:, :] = 0
        grad_cols[..., 1:, :] += grad_y - upper
        # columns: the left element wins ties
        left = grad_cols * (x[..., :-1] >= x[..., 1:]).to(grad_y.dtype)
        grad_x = grad_y.new_empty(x.shape)
        grad_x[..., :-1] = left
        grad_x[..., -1:] = 0
        grad_x[..., 1:] += grad_cols - left
        return grad_x


def max_pool_2x2_stride1(x: torch.Tensor) -> torch.Tensor:
    """2×2 max-pooling with stride 1 over the last two dimensions.

    Equal to ``F.max_pool2d(x, kernel_size=2, stride=1)`` (values and gradients) but
    computed as a separable max over shifted views, which on CPU avoids
    ``max_pool2d_with_indices`` (measured several times slower in the forward pass).

    Args:
        x: (..., H, W) tensor.

    Returns:
        (..., H - 1, W - 1) tensor.
    """
    if x.requires_grad and torch.is_grad_enabled():
        return _MaxPool2x2Stride1.apply(x)
    cols = torch.maximum(x[..., :-1], x[..., 1:])
    return torch.maximum(cols[..., :-1, :], cols[..., 1:, :])


def relative_log(obs: torch.Tensor, reference: torch.Tensor | None = None) -> torch.Tensor:
    """Signed log of each window's potential relative to its centre cell.

    ``sign(d) · log(1 + |d|)`` with ``d = U − U(centre)``, per channel. The robot's own
    cell reads 0, downhill negative, uphill positive; obstacles and the map's outside
    (which read the map's highest potential) stand out as a clear maximum, whatever the
    absolute level of U where the robot is.

    Args:
        obs: (N, C, k, k) raw potential windows.
        reference: (N, 1, k, k) the window whose centre every channel is taken relative to
            (default: each channel's own centre).

    Returns:
        (N, C, k, k) transformed windows.
    """
    c = obs.shape[-1] // 2
    ref = obs if reference is None else reference
    d = obs - ref[..., c : c + 1, c : c + 1]
    return signed_log(d)


class QNetwork(nn.Module):
    """The thesis's convolutional Q-network with an optional observation transform.

    Args:
        obs_shape: (C, k, k) observation shape.
        filters: Output channels of each 2×2 convolution, e.g. (10, 10, 20) (Table 3)
            or (4, 4) (Table 4).
        hidden: Widths of the hidden fully connected layers (the thesis: (32, 32)).
        n_actions: Number of actions (9, Model Table 1).
        negative_slope: Leaky ReLU slope λ.
        pooled_convs: How many of the leading convolutions are followed by a max-pool
            (the thesis: 2).
        obs_transform: ``"raw"`` (the observation as it comes), ``"relative-log"``
            (:func:`relative_log` on every channel) or ``"relative-log-memory"``
            (:func:`relative_log` on channel 0, the potential; the other channels, e.g. the
            visit memory of ``NavigateEnv(memory=True)``, pass through unchanged) or
            ``"relative-log-previous"`` (channels 0 and 1, the potential now and one step
            earlier of ``NavigateEnv(previous=True)``, both relative to the centre of channel 0,
            so their difference is the obstacles' motion; the others pass through).

    Raises:
        ValueError: A window too small for the layers, or an unknown transform.
    """

    def __init__(
        self,
        obs_shape: Sequence[int] = (1, 11, 11),
        filters: Sequence[int] = (10, 10, 20),
        hidden: Sequence[int] = (32, 32),
        n_actions: int = 9,
        negative_slope: float = 0.001,
        pooled_convs: int = 2,
        obs_transform: str = "raw",
    ):
        super().__init__()
        if obs_transform not in OBS_TRANSFORMS:
            raise ValueError(f"obs_transform must be one of {OBS_TRANSFORMS}, not {obs_transform!r}")
        channels, height, width = (int(v) for v in obs_shape)
        self.arch = {
            "obs_shape": [channels, height, width],
            "filters": [int(f) for f in filters],
            "hidden": [int(h) for h in hidden],
            "n_actions": int(n_actions),
            "negative_slope": float(negative_slope),
            "pooled_convs": int(pooled_convs),
            "obs_transform": obs_transform,
        }
        """Everything needed to build this network again (saved with its weights)."""
        self.negative_slope = float(negative_slope)
        self.pooled_convs = int(pooled_convs)
        self.obs_transform = obs_transform

        self.convs = nn.ModuleList()
        for i, f in enumerate(filters):
            self.convs.append(nn.Conv2d(channels, f, kernel_size=2))
            channels = f
            height, width = height - 1, width - 1
            if i < pooled_convs:
                height, width = height - 1, width - 1
        if height < 1 or width < 1:
            raise ValueError(f"observation {tuple(obs_shape)} is too small for {len(filters)} convolutions")
        sizes = [channels * height * width, *hidden]
        self.hidden = nn.ModuleList(nn.Linear(a, b) for a, b in zip(sizes[:-1], sizes[1:]))
        self.head = nn.Linear(sizes[-1], n_actions)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """Action values for a batch of raw observations.

        Args:
            obs: (N, C, k, k) float32 raw observations.

        Returns:
            (N, n_actions) action values.
        """
        if self.obs_transform == "relative-log":
            x = relative_log(obs)
        elif self.obs_transform == "relative-log-memory":
            x = torch.cat([relative_log(obs[:, :1]), obs[:, 1:]], dim=1)
        elif self.obs_transform == "relative-log-previous":
            x = torch.cat([relative_log(obs[:, :2], obs[:, :1]), obs[:, 2:]], dim=1)
        else:
            x = obs
        for i, conv in enumerate(self.convs):
            x = F.leaky_relu(conv(x), self.negative_slope)
            if i < self.pooled_convs:
                x = max_pool_2x2_stride1(x)
        x = x.flatten(1)
        for layer in self.hidden:
            x = F.leaky_relu(layer(x), self.negative_slope)
        return self.head(x)
