"""From frames to a latent state: the vision half of a model-based run on pixels (thesis 6.1).

A convolutional autoencoder squeezes a grey frame into a code z of a few numbers and draws the frame back from it;
it is fitted to the real frames seen so far by the reconstruction's binary cross-entropy (pixels in [0, 1]). An
observation of stacked frames becomes the newest frame's code and its changes since the older frames: the latent
state everything else works on. The recurrent world model learns its dynamics (``drrl.models.recurrent``, with
overshooting and dynamical consistency), the reward and end are learned from it (``drrl.models.outcome``), imagined
episodes run in latent space, and the policy acts on it. ``Encoding`` puts the encoder in front of a real env, so
that real episodes and measurements give the policy the latent state too.

The split is World Models' (Ha & Schmidhuber 2018: a vision model V, then a memory model M on its latents, then a
small controller searched by an evolution strategy); ours is a deterministic autoencoder rather than a VAE, since
the recurrent model does its own regularisation (overshooting) and PGPE explores in parameter space.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import VectorEnv, VectorObservationWrapper
from gymnasium.vector.utils import batch_space
from torch import nn

STILL = 1e-3  # a keypoint's spread under 1/30 of a pixel (frame units, 2 across 64 pixels) is not motion


class FrameAutoencoder(nn.Module):
    """One grey frame (N, 1, H, W) uint8 → z (N, latent) → the frame. The encoder is a deep spatial autoencoder's
    (Finn et al. 2016, learning visuomotor control from frames): three convolutions (16, 32, then latent / 2
    channels, two of stride 2) make latent / 2 feature maps of H/4 × W/4 cells; each map's softmax over its cells is
    a distribution, and z is the expected (x, y) of each, in [−1, 1] across the frame: keypoints, which move
    smoothly with the things drawn, to a fraction of a pixel. The decoder draws the frame back from z: a linear layer
    to (32, H/16, W/16), then four transposed convolutions of stride 2. Narrow, since a CPU fits it in every iteration
    of a run: 64 × 64 frames cost about 40 ms an update of 64 frames on one core.

    Why keypoints rather than a linear layer from the convolutions to z: the motion of one control period is a
    fraction of a pixel, and only read well off codes that are smooth, near-linear functions of where things are.
    Fitted to the cart-pole's frames of 40 episodes of random linear feedback, an affine read-out of (s, ṡ, θ, θ̇)
    off the features scores R² 0.998 / 0.84 / 0.98 / 0.73 on fresh episodes' frames, against 0.91 / 0.38 / 0.41 /
    0.33 from a linear code of the same size (medians of 3 seeds, ``benchmarks/pixels.py --codes``).

    An observation of F stacked frames (oldest first) is read as the newest frame's code and, for each older frame,
    the difference of the newest code from its code: ``features`` = F × latent numbers, each standardised over the
    observations of the last fit. The differences carry the motion: the keypoints' velocities.
    """

    feature_mean: torch.Tensor
    feature_std: torch.Tensor
    grid_x: torch.Tensor
    grid_y: torch.Tensor

    def __init__(self, frame_shape: tuple[int, int, int] = (2, 64, 64), latent: int = 8):
        super().__init__()
        frames, height, width = frame_shape
        if height % 16 or width % 16:
            raise ValueError(f"frames must be a multiple of 16 pixels high and wide, got {height} × {width}")
        if latent % 2:
            raise ValueError(f"a frame's code is keypoints, (x, y) each: latent must be even, got {latent}")
        self.frame_shape, self.latent, self.features = tuple(frame_shape), latent, frames * latent
        maps = latent // 2
        self.encoder = nn.Sequential(  # to the feature maps; ``forward`` takes their keypoints
            nn.Conv2d(1, 16, 5, 2, 2), nn.ReLU(), nn.Conv2d(16, 32, 3, 2, 1), nn.ReLU(), nn.Conv2d(32, maps, 3, 1, 1)
        )
        rows, columns = height // 4, width // 4
        self.register_buffer("grid_x", ((torch.arange(columns) + 0.5) * 2 / columns - 1).repeat(rows))
        self.register_buffer("grid_y", ((torch.arange(rows) + 0.5) * 2 / rows - 1).repeat_interleave(columns))
        self.grid = (32, height // 16, width // 16)
        widths, cells = (1, 8, 16, 32, 32), int(np.prod(self.grid))
        up = [layer for a, b in pairwise(widths[::-1]) for layer in (nn.ConvTranspose2d(a, b, 4, 2, 1), nn.ReLU())]
        self.decoder = nn.Sequential(nn.Linear(latent, cells), nn.ReLU(), nn.Unflatten(1, self.grid), *up[:-1])
        self.register_buffer("feature_mean", torch.zeros(self.features))
        self.register_buffer("feature_std", torch.ones(self.features))

    def settings(self) -> dict:
        return {"frame_shape": self.frame_shape, "latent": self.latent}

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        """z (N, latent) of single frames (N, 1, H, W), uint8 or already in [0, 1]."""
        pixels = frames.float() / 255 if frames.dtype == torch.uint8 else frames
        where = torch.softmax(self.encoder(pixels).flatten(2), dim=-1)  # (N, latent / 2, cells)
        return torch.cat([where @ self.grid_x, where @ self.grid_y], dim=1)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """Frames (N, 1, H, W) in [0, 1] drawn from z (N, latent)."""
        return torch.sigmoid(self.decoder(z))

    @torch.inference_mode()
    def encode(self, observations: np.ndarray, batch: int = 1024) -> np.ndarray:
        """The standardised features (N, F × latent) float32 of observations (N, F, H, W) uint8, in batches."""
        return ((self._features(observations, batch) - self.feature_mean) / self.feature_std).cpu().numpy()

    @torch.inference_mode()
    def draw(self, features: np.ndarray) -> np.ndarray:
        """The newest frames (N, 1, H, W) uint8 drawn from standardised features (N, F × latent)."""
        device = self.feature_mean.device
        raw = torch.as_tensor(features, device=device) * self.feature_std + self.feature_mean
        return (255 * self.decode(raw[:, : self.latent])).round().to(torch.uint8).cpu().numpy()

    @torch.inference_mode()
    def standardise(self, observations: np.ndarray) -> np.ndarray:
        """Set the features' mean and std to those over ``observations``; their standardised features (``encode``'s),
        from this one pass of the encoder. A spread below ``STILL`` counts as ``STILL``, so that a keypoint that
        follows nothing is not blown up into noise of unit size."""
        features = self._features(observations)
        self.feature_mean.copy_(features.mean(0))
        spread = features.std(0).clamp_min(STILL) if len(features) > 1 else torch.ones_like(self.feature_std)
        self.feature_std.copy_(spread)
        return ((features - self.feature_mean) / self.feature_std).cpu().numpy()

    def _features(self, observations: np.ndarray, batch: int = 1024) -> torch.Tensor:
        rows = [self._read(observations[i : i + batch]) for i in range(0, len(observations), batch)]
        return torch.cat(rows) if rows else torch.zeros((0, self.features), device=self.feature_mean.device)

    def _read(self, observations: np.ndarray) -> torch.Tensor:
        """The raw features of a batch: the newest frame's code, then its differences from the older frames'."""
        n, frames = observations.shape[:2]
        pixels = torch.as_tensor(observations, device=self.feature_mean.device)
        z = self(pixels.reshape(n * frames, 1, *self.frame_shape[1:])).reshape(n, frames, self.latent)
        newest = z[:, -1]
        return torch.cat([newest, *(newest - z[:, i] for i in range(frames - 2, -1, -1))], dim=1)


@dataclass(frozen=True)
class FrameFit:
    """How one fit of the autoencoder went."""

    updates: int
    loss: float  # over the last 50 updates: the reconstruction's binary cross-entropy a pixel
    features: np.ndarray  # the fitted observations' standardised features (N, F × latent), as ``encode`` gives them


def fit_autoencoder(
    model: FrameAutoencoder,
    observations: np.ndarray,
    updates: int,
    batch_size: int = 64,
    lr: float = 3e-3,
    seed: int = 0,
) -> FrameFit:
    """Fit ``model`` in place to the newest frames of observations (N, F, H, W) uint8 (every frame of an episode is
    the newest of one of its observations) by Adam on random minibatches, then standardise its features over the
    observations; the later fits of a run start from the previous weights, so that the codes move little between
    them."""
    frames = observations[:, -1:]
    generator = torch.Generator().manual_seed(seed)
    device = next(model.parameters()).device
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    losses = []
    for _ in range(updates):
        index = torch.randint(len(frames), (min(batch_size, len(frames)),), generator=generator)
        pixels = torch.as_tensor(frames[index.numpy()], device=device).float() / 255
        loss = nn.functional.binary_cross_entropy_with_logits(model.decoder(model(pixels)), pixels)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(float(loss.detach()))
    features = model.standardise(observations)
    return FrameFit(updates, float(np.mean(losses[-50:])) if losses else float("nan"), features)


class Encoding(VectorObservationWrapper):
    """A frames env whose observations are the autoencoder's standardised features: what the policy reads in
    reality. The encoder is shared, so a refitted one encodes from the next observation on."""

    def __init__(self, env: VectorEnv, model: FrameAutoencoder):
        super().__init__(env)
        self.model = model
        bound = np.finfo(np.float32).max
        self.single_observation_space = spaces.Box(-bound, bound, (model.features,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, env.num_envs)

    def observations(self, observations: np.ndarray) -> np.ndarray:
        return self.model.encode(np.asarray(observations))
