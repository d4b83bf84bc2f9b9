"""A motion answer in json (POST /generate, POST /edit), and every error answer's body."""
from __future__ import annotations

from pydantic import (
    BaseModel,
    Field,
)


class SegmentSpanOut(BaseModel):
    text: str
    start_frame: int = Field(description="First frame of the segment.")
    end_frame: int = Field(description="One past the last frame (exclusive), = the next segment's start_frame.")


class ModelInfo(BaseModel):
    name: str
    version: str


class MotionResponse(BaseModel):
    """The json answer: joint positions in metres, Y up, first frame facing +Z."""

    fps: int
    joints: list[str] = Field(description="The 22 SMPL joint names, in the order of frames' second axis.")
    parents: list[int] = Field(description="Parent index of each joint (-1 for the root).")
    frames: list[list[list[float]]] = Field(description="[T][22][3] positions in metres.")
    segments: list[SegmentSpanOut]
    seed: int
    model: ModelInfo
    warnings: list[str] = Field(default_factory=list)
    handle: str | None = Field(
        None, description="The motion's codes, segments and options in one compact string (`t2m1.` + base64url; "
                          "docs/api.md): send it to POST /edit to change some segments and keep the others. A "
                          "diffusion model's is its recipe instead (`t2m2.`: seed, guidance, segments and the edits "
                          "made since, which make its frames again exactly).")


class ErrorResponse(BaseModel):
    detail: str
