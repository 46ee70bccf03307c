"""Configuration of the network architecture and of a training run."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

#: Filters per U-Net level in the paper.
PAPER_FILTERS: tuple[int, ...] = (32, 64, 128, 192)


class ConfigError(ValueError):
    """A configuration value is out of range."""

    def __init__(self, field_name: str, reason: str) -> None:
        self.field_name = field_name
        self.reason = reason
        super().__init__(f"{field_name}: {reason}")


def parse_filters(text: str) -> tuple[int, ...]:
    """Parse a comma-separated filter list such as ``"8,16,32,48"``."""
    try:
        filters = tuple(int(part) for part in text.split(",") if part.strip())
    except ValueError as err:
        raise ConfigError("filters", f"not a comma-separated list of integers: {text!r}") from err
    return filters


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of the probabilistic U-Net.

    Defaults are the paper's (REFERENCE.md section 3): 4 levels with
    ``filters = (32, 64, 128, 192)``, 3 conv3x3+ReLU per level, latent dim 6, fcomb of
    three 1x1 conv+ReLU with 32 channels, 2x64x64 flow input.
    """

    #: Output channels of each U-Net level (and of the prior/posterior encoders).
    filters: tuple[int, ...] = PAPER_FILTERS
    #: Convolutions (3x3 + ReLU) per level.
    convs_per_level: int = 3
    #: Dimension of the latent Gaussian.
    latent_dim: int = 6
    #: Channels of the hidden fcomb layers; ``None`` means ``filters[0]`` (32 in the paper).
    fcomb_channels: int | None = None
    #: Number of hidden 1x1 conv+ReLU layers in fcomb.
    fcomb_layers: int = 3
    #: Side of the square input, pixels (must be divisible by ``2 ** (levels - 1)``).
    input_size: int = 64
    #: Flow channels (u, v).
    input_channels: int = 2

    def __post_init__(self) -> None:
        object.__setattr__(self, "filters", tuple(int(f) for f in self.filters))
        if len(self.filters) < 1 or any(f < 1 for f in self.filters):
            raise ConfigError("filters", f"need at least one positive entry, got {self.filters}")
        if self.convs_per_level < 1:
            raise ConfigError("convs_per_level", f"must be >= 1, got {self.convs_per_level}")
        if self.latent_dim < 1:
            raise ConfigError("latent_dim", f"must be >= 1, got {self.latent_dim}")
        if self.fcomb_channels is not None and self.fcomb_channels < 1:
            raise ConfigError("fcomb_channels", f"must be >= 1, got {self.fcomb_channels}")
        if self.fcomb_layers < 1:
            raise ConfigError("fcomb_layers", f"must be >= 1, got {self.fcomb_layers}")
        step = 2 ** (len(self.filters) - 1)
        if self.input_size < step or self.input_size % step != 0:
            raise ConfigError(
                "input_size", f"{self.input_size} is not a positive multiple of {step} (2^(levels-1))"
            )

    @property
    def feature_channels(self) -> int:
        """Channels of the U-Net's last decoder map (``C`` in the bundle contract)."""
        return self.filters[0]

    @property
    def fcomb_width(self) -> int:
        """Resolved fcomb hidden width."""
        return self.fcomb_channels if self.fcomb_channels is not None else self.filters[0]

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form (used in checkpoints)."""
        out = asdict(self)
        out["filters"] = list(self.filters)
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModelConfig:
        """Inverse of :meth:`to_dict`."""
        data = dict(data)
        data["filters"] = tuple(data["filters"])
        return cls(**data)


@dataclass
class FitConfig:
    """Everything a training run needs. Defaults are the paper's."""

    #: Dataset directory (``manifest.json`` + per-episode ``.npy``), see docs/model-bundle.md.
    dataset_dir: str
    #: Run folder: checkpoints, logs, ``model.vamos``.
    run_dir: str
    #: Architecture.
    model: ModelConfig = field(default_factory=ModelConfig)
    #: Total number of epochs.
    epochs: int = 50
    #: Samples per optimiser step.
    batch_size: int = 128
    #: Adam learning rate.
    learning_rate: float = 1e-4
    #: Weight of KL(posterior || prior) in the loss (reached after ``kl_warmup_epochs``).
    beta: float = 10.0
    #: Free bits, nats per latent dimension (0: off): the loss uses, per latent dimension,
    #: ``max(batch-mean KL of that dimension, free_bits)`` (see :mod:`vamos.train.losses`).
    free_bits: float = 0.0
    #: KL annealing: the KL weight of epoch ``k`` (1-based) is ``beta * min(1, (k - 1) / W)``
    #: with ``W = kl_warmup_epochs`` (0: off, ``beta`` from the first epoch).
    kl_warmup_epochs: int = 0
    #: Coefficient of the weight-norm regulariser (see :func:`vamos.train.losses.weight_norm`).
    weight_decay: float = 1e-5
    #: Smallest past offset ``A`` (processed flow frames).
    a: int = 5
    #: Offset range ``B``: ``n`` is uniform on ``{A, ..., A + B}``.
    b: int = 4
    #: Prior samples per offset at inference (written to the bundle manifest).
    m: int = 10
    #: Fraction of episodes held out for validation (ignored if ``val_episodes`` is given).
    val_fraction: float = 0.1
    #: Explicit validation episode names; ``None`` means a seeded random split.
    val_episodes: list[str] | None = None
    #: Explicit training episode names; ``None`` means all episodes not in validation.
    train_episodes: list[str] | None = None
    #: Seed of everything random (weights, split, sampling, latent noise).
    seed: int = 0
    #: ``"auto"`` (cuda if available, else cpu), ``"cpu"``, ``"cuda"``, ``"cuda:1"``...
    device: str = "auto"
    #: CPU threads for torch; ``None`` leaves torch's default.
    threads: int | None = None
    #: Model name in the bundle manifest; ``None`` means the run folder's name.
    name: str | None = None
    #: Store activations channels-last (NHWC). ``None``: NHWC on CPU (paper-width training
    #: steps took about half the time of NCHW on a 2-core VM), NCHW on CUDA.
    channels_last: bool | None = None
    #: Keep a copy of the checkpoint every this many epochs (0: only ``last.pt``).
    keep_every: int = 0
    #: Show tqdm progress bars.
    progress: bool = True

    def validate(self) -> None:
        """Raise :class:`ConfigError` for out-of-range values."""
        if self.epochs < 1:
            raise ConfigError("epochs", f"must be >= 1, got {self.epochs}")
        if self.batch_size < 1:
            raise ConfigError("batch_size", f"must be >= 1, got {self.batch_size}")
        if not self.learning_rate > 0:
            raise ConfigError("learning_rate", f"must be > 0, got {self.learning_rate}")
        if not self.beta >= 0:
            raise ConfigError("beta", f"must be >= 0, got {self.beta}")
        if not self.weight_decay >= 0:
            raise ConfigError("weight_decay", f"must be >= 0, got {self.weight_decay}")
        if (isinstance(self.free_bits, bool) or not isinstance(self.free_bits, (int, float))
                or not math.isfinite(self.free_bits) or self.free_bits < 0):
            raise ConfigError("free_bits", f"must be a finite number >= 0 (nats per latent dimension), "
                                           f"got {self.free_bits!r}")
        if (isinstance(self.kl_warmup_epochs, bool) or not isinstance(self.kl_warmup_epochs, int)
                or self.kl_warmup_epochs < 0):
            raise ConfigError("kl_warmup_epochs", f"must be an integer >= 0, got {self.kl_warmup_epochs!r}")
        if self.a < 1:
            raise ConfigError("a", f"must be >= 1, got {self.a}")
        if self.b < 0:
            raise ConfigError("b", f"must be >= 0, got {self.b}")
        if self.m < 1:
            raise ConfigError("m", f"must be >= 1, got {self.m}")
        if not 0.0 <= self.val_fraction < 1.0:
            raise ConfigError("val_fraction", f"must be in [0, 1), got {self.val_fraction}")
        if self.threads is not None and self.threads < 1:
            raise ConfigError("threads", f"must be >= 1, got {self.threads}")
        if self.keep_every < 0:
            raise ConfigError("keep_every", f"must be >= 0, got {self.keep_every}")

    def effective_beta(self, epoch: int) -> float:
        """KL weight of 1-based ``epoch``: ``beta * min(1, (epoch - 1) / kl_warmup_epochs)``.

        Without warm-up (``kl_warmup_epochs = 0``) it is ``beta`` in every epoch; with ``W``
        warm-up epochs it is 0 in epoch 1, ``beta / W`` in epoch 2, ... and ``beta`` from
        epoch ``W + 1`` on.
        """
        if self.kl_warmup_epochs <= 0:
            return float(self.beta)
        return float(self.beta) * min(1.0, (epoch - 1) / self.kl_warmup_epochs)
