"""Inpainting a masked-family token map: some tokens are known and kept, the others are filled by the same loop.

An edit of a masked-family motion (POST /edit) does not sample its segment alone: it hands the loop a map whose rows
are the kept codes before the edit, the edited span and the kept codes after it, with `fill` marking the tokens to
sample (a whole span's rows, or only some columns of them: a body part). The loop then runs unchanged: the known
tokens start unmasked with infinite confidence, so the re-masking schedule (counted over the tokens to fill) never
masks them, and every step's prediction sees them on both sides as context; the residual stage predicts each layer
for the whole map and the known tokens' codes are put back after each pass, so later layers see the kept codes. The
map's `keep` rows (the edited segment) are what comes back.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Inpaint"]


@dataclass(frozen=True)
class Inpaint:
    """One segment's map to inpaint: `known` int64 [rows, C, R] codes (any value where `fill`), `fill` bool
    [rows, C] the tokens to sample, `keep` (start, stop) the rows answered."""

    known: np.ndarray
    fill: np.ndarray
    keep: tuple[int, int]

    def __post_init__(self) -> None:
        rows = len(self.known)
        if self.known.ndim != 3 or self.fill.shape != self.known.shape[:2] or rows < 1:
            raise ValueError(f"known codes {self.known.shape} and fill {self.fill.shape} must be [rows, C, R] and "
                             "[rows, C], rows >= 1")
        if not 0 <= self.keep[0] < self.keep[1] <= rows:
            raise ValueError(f"keep {self.keep} must be rows within 0..{rows}")

    @property
    def rows(self) -> int:
        return len(self.known)

    def columns(self, start: int, stop: int) -> Inpaint:
        """The same map cut to columns start..stop (a further generator's own columns)."""
        return Inpaint(self.known[:, start:stop], self.fill[:, start:stop], self.keep)

    def first_layer(self, mask_id: int) -> tuple[np.ndarray, np.ndarray]:
        """(tokens, scores) flattened as the loop keeps them: known tokens with infinite confidence (never masked),
        the tokens to fill masked."""
        fill = self.fill.reshape(-1)
        tokens = np.where(fill, mask_id, self.known[..., 0].reshape(-1)).astype(np.int64)
        return tokens, np.where(fill, 0.0, np.inf)

    def counts(self, schedule: list[int]) -> list[int]:
        """The re-masking counts of a map with only the tokens to fill (`schedule`: remask_counts of their number);
        nothing to fill (a generator whose columns are all kept) masks nothing."""
        return schedule if self.fill.any() else [0] * len(schedule)

    def restore(self, codes: np.ndarray, layer: int | None = None) -> None:
        """Put the known codes back in `codes` [rows, C, R] (in place): one layer, or every layer."""
        kept = ~self.fill
        if layer is None:
            codes[kept] = self.known[kept]
        else:
            codes[..., layer][kept] = self.known[..., layer][kept]

    def answer(self, codes: np.ndarray) -> np.ndarray:
        """The rows answered for the segment: `keep`, its known tokens exactly as they were."""
        out = np.array(codes[:self.rows], dtype=np.int64)
        self.restore(out)
        return out[self.keep[0]:self.keep[1]]
