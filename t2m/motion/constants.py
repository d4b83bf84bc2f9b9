"""The motion constants every package shares, in one place.

FPS is HumanML3D's frame rate, which the motion core, the training set and every bundle so far use. FRAMES_PER_TOKEN
is the temporal downsampling of this project's VQ-VAEs (two stride-2 convolutions): one code per 4 frames. A bundle
declares its own `fps` and `frames_per_token` in its manifest; these are the defaults the code writes and assumes
where no manifest is involved.
"""
from __future__ import annotations

__all__ = ["FPS", "FRAMES_PER_TOKEN"]

FPS = 20
FRAMES_PER_TOKEN = 4
