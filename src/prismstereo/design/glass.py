"""Glasses a prism can be made of: refractive index at the d line (587.6 nm) and Abbe number.

The table holds catalogue values of common optical materials (Schott N-BK7, fused silica, PMMA, polycarbonate);
any other glass is given by its index as ``"n=1.52"`` (no Abbe number, so no dispersion in renders).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from prismstereo.errors import ConfigError

__all__ = ["GLASSES", "Glass", "parse_glass", "parse_glasses"]


@dataclass(frozen=True)
class Glass:
    """A prism material.

    Attributes
    ----------
    name : str
    n_d : float
        Refractive index at the helium d line (587.6 nm), > 1.
    abbe : float or None
        Abbe number V_d = (n_d − 1) / (n_F − n_C); None when unknown (an ``n=…`` glass).
    """

    name: str
    n_d: float
    abbe: float | None = None

    def __post_init__(self) -> None:
        if isinstance(self.n_d, bool) or not isinstance(self.n_d, int | float) or not math.isfinite(self.n_d) \
                or not 1.0 < self.n_d < 4.0:
            raise ConfigError(f"glass {self.name!r} n_d: expected a refractive index in (1, 4), got {self.n_d!r}")
        if self.abbe is not None and not (math.isfinite(self.abbe) and self.abbe > 0):
            raise ConfigError(f"glass {self.name!r} abbe: expected a positive Abbe number, got {self.abbe!r}")
        object.__setattr__(self, "n_d", float(self.n_d))


#: catalogue glasses by name: (n_d, V_d)
GLASSES: dict[str, Glass] = {
    "N-BK7": Glass("N-BK7", 1.5168, 64.17),
    "fused-silica": Glass("fused-silica", 1.4585, 67.8),
    "PMMA": Glass("PMMA", 1.4905, 57.2),
    "polycarbonate": Glass("polycarbonate", 1.585, 29.9),
}
_ALIASES = {"nbk7": "N-BK7", "bk7": "N-BK7", "fusedsilica": "fused-silica", "silica": "fused-silica",
            "quartz": "fused-silica", "pmma": "PMMA", "acrylic": "PMMA", "polycarbonate": "polycarbonate",
            "pc": "polycarbonate"}


def parse_glass(text: str | Glass) -> Glass:
    """A :class:`Glass` from a catalogue name (case and ``-``/``_``/space insensitive) or ``"n=1.5"``."""
    if isinstance(text, Glass):
        return text
    raw = str(text).strip()
    if raw.lower().startswith("n="):
        try:
            n = float(raw[2:])
        except ValueError:
            raise ConfigError(f"glass: expected n=<index> like n=1.5, got {raw!r}") from None
        return Glass(f"n={n:g}", n, None)
    key = raw.lower().replace("-", "").replace("_", "").replace(" ", "")
    if key in _ALIASES:
        return GLASSES[_ALIASES[key]]
    raise ConfigError(f"glass: expected one of {', '.join(GLASSES)} or n=<index>, got {raw!r}")


def parse_glasses(text: str | Glass | tuple[str | Glass, ...] | list[str | Glass]) -> tuple[Glass, ...]:
    """One or more glasses: a :class:`Glass`, a name, ``"n=…"``, a comma-separated list or a sequence of them."""
    if isinstance(text, Glass):
        return (text,)
    items = [t for t in str(text).split(",")] if isinstance(text, str) else list(text)
    out = tuple(parse_glass(t.strip() if isinstance(t, str) else t) for t in items if not (isinstance(t, str)
                                                                                          and not t.strip()))
    if not out:
        raise ConfigError(f"glass: expected at least one glass name or n=<index>, got {text!r}")
    return out
