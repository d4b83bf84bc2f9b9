"""Service configuration from the environment (prefix T2M_), one typed object passed to `create_app`.

Every knob an operator may need in production lives here so that the container, the CLI and the tests configure
the service the same way: `T2M_MAX_QUEUE=4 t2m serve` and `create_app(Settings(max_queue=4))` are equivalent.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import AliasChoices, Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from t2m.bundles import BUNDLE_ENVIRONMENT, DEFAULT_BUNDLE

if TYPE_CHECKING:
    from t2m.runtime.execution import Execution

__all__ = ["Settings", "default_bundle_path"]


def default_bundle_path() -> Path:
    """The embedded default model, shipped inside the package (t2m/bundles/default), wherever it is installed."""
    return DEFAULT_BUNDLE


Provider = Literal["cpu", "cuda"]


def _cpu_only() -> list[Provider]:
    return ["cpu"]


class Settings(BaseSettings):
    """All settings; each field can be set by the environment variable T2M_<FIELD NAME IN CAPITALS>."""

    model_config = SettingsConfigDict(env_prefix="T2M_", extra="ignore", populate_by_name=True)

    bundle_path: Path = Field(
        default_factory=default_bundle_path,
        validation_alias=AliasChoices("bundle_path", *BUNDLE_ENVIRONMENT),
        description="Model bundle directory of the default model (env T2M_BUNDLE_PATH or T2M_MODEL_DIR); "
                    "default: the embedded t2m/bundles/default.",
    )
    extra_model_dirs: Annotated[list[Path], NoDecode] = Field(
        default_factory=list,
        description="Further model bundle directories served next to the default, comma-separated in the env; "
                    "a request picks one by its manifest name (the request's `model` field).")
    # 1 by default: measured on 2-core machines, one thread per session serves the embedded models 2.5-3.6x faster
    # at batch 1 and 16-30% more motions/s at 16 clients than onnxruntime's own choice (README "Speed")
    intra_op_threads: int = Field(1, ge=0, description="onnxruntime intra-op threads per session (0 = ORT's choice: "
                                                       "all cores, faster only for release-size imported models).")
    inter_op_threads: int = Field(1, ge=0, description="onnxruntime inter-op threads per session.")
    # 1 by default: the engine's own numpy work is small (the unknown-sentence index, joints from features), and
    # numpy's BLAS threads left at its default spin beside onnxruntime's thread (measured: a 10 s motion's CPU time
    # 204 -> 132 ms per request with one, docs/speed-history.md)
    blas_threads: int = Field(1, ge=0, description="numpy's BLAS threads in the service process (0 = BLAS's own "
                                                   "choice: one per core).")
    # on by default: the decoding loops allocate many small objects per step, and with the loaded libraries'
    # objects in the collector's view its full collections took ~30% of the default model's host loop at batch
    # 1,024 (t2m/bench/host_loop.py --gc as-is,frozen; docs/gpu.md)
    gc_freeze: bool = Field(True, description="After the models load, move every object alive then out of the "
                                              "garbage collector's generations (gc.freeze), so its collections "
                                              "walk only what requests allocate.")
    execution_providers: Annotated[list[Provider], NoDecode] = Field(
        default_factory=_cpu_only, min_length=1,
        description="onnxruntime execution providers of the model sessions, in order, comma-separated in the env: "
                    "'cpu', or 'cuda' (CUDA, then CPU for what CUDA lacks; needs onnxruntime-gpu: the 'gpu' "
                    "extra). A provider the installed onnxruntime lacks stops the start-up with a one-line error "
                    "naming this setting (`t2m serve --providers`).")
    io_binding: Literal["auto", "on", "off"] = Field(
        "auto", description="Keep the step graphs' key/value caches on the device between steps (onnxruntime "
                            "I/O binding): 'auto' = on when the providers include a GPU, 'on' also on CPU (the "
                            "tests), 'off' never.")
    cuda_graphs: bool = Field(
        False, description="Replay step graphs as CUDA graphs (needs 'cuda' in execution_providers): the masked "
                            "family's token graphs, the diffusion family's denoiser, and a GPT bundle's "
                            "gpt_step_fixed.onnx (t2m import t2m-gpt --cuda-graph-step). One launch per call "
                            "instead of one per kernel: a MoMask-size request 56 -> 24 ms on an H100 (docs/gpu.md). "
                            "A graph onnxruntime will not capture (older exports) is served without, with a warning.")
    cuda_graph_shapes: int = Field(16, ge=1, le=1024, description="With cuda_graphs: how many input shapes (batch "
                                   "size x rows) each graph captures, the first ones seen; later shapes run "
                                   "uncaptured (each capture holds device memory for the process's life).")
    engine_workers: int = Field(1, ge=1, le=16, description="Worker threads that run batches of generations (with "
                                "continuous batching each has a helper thread for the text and decoder work of "
                                "requests that join or leave while it steps).")
    max_queue: int = Field(16, ge=1, description="Requests allowed to wait for a worker; one more gets 429.")
    max_batch_rows: int = Field(64, ge=1, description="Rows a batch of any family holds (segments, x2 with guidance: "
                                "conditioned and null); a diffusion edit takes a whole batch.")
    batch_window_ms: float = Field(5.0, ge=0, description="How long a batch waits for more requests to join it (with "
                                                          "continuous batching: how long a request waits before "
                                                          "joining a running batch, so that simultaneous ones start "
                                                          "together).")
    continuous_batching: bool = Field(
        True, description="The autoregressive families (GPT and T2M-HiFiGPT): a request joins the running batch at "
                          "the next step boundary and is answered as soon as its own codes are done (false: each "
                          "batch runs to its end first). The masked family always runs batches to their end.")
    step_order: Literal["shortest-first", "every-cohort"] = Field(
        "shortest-first", description="With continuous batching, which running cohorts step at each step boundary: "
                                      "'shortest-first' runs the cohort holding the smallest request (and those "
                                      "whose smallest is at most twice its size, and any passed over max_step_skips "
                                      "times in a row), so a short request is not slowed by long ones beside it; "
                                      "'every-cohort' steps them all every time (the order before 0.4).")
    max_step_skips: int = Field(
        3, ge=0, le=16, description="shortest-first: a cohort is passed over at most this many step boundaries in a "
                                    "row (0 = never: every cohort steps every time), which bounds what long "
                                    "requests lose to short ones.")
    request_timeout_s: float = Field(60.0, gt=0, description="A generation taking longer answers 504.")
    max_body_bytes: int = Field(64 * 1024, ge=1024, description="Larger request bodies answer 413.")
    # uvicorn has no such deadlines: without them a half-sent request holds its connection for ever
    header_timeout_s: float = Field(
        15.0, gt=0, description="A request's headers must be complete this long after the connection opened or the "
                                "request's first byte; later: 408 and the connection closed (`t2m serve`).")
    body_timeout_s: float = Field(
        30.0, gt=0, description="A request's body must be complete this long after its headers; later: 408 and the "
                                "connection closed (`t2m serve`).")
    keep_alive_s: int = Field(
        10, ge=1, le=600, description="An idle kept-alive connection is closed after this long (`t2m serve`); longer "
                                        "than common clients keep theirs (httpx: 5 s), so that a client never sends "
                                        "on a connection the server is closing at that moment.")
    api_key: SecretStr | None = Field(None, description="If set, POST /generate and POST /edit need 'Authorization: "
                                                                "Bearer <key>'.")
    cors_origins: Annotated[list[str], NoDecode] = Field(
        default_factory=list, description="Allowed CORS origins, comma-separated in the env ('*' = any).")
    retry_after_s: int = Field(1, ge=1, description="Retry-After seconds sent with 429 and 503 answers.")
    verify_hashes: bool = Field(True, description="Check every bundle file's sha256 at load (slower start).")
    stream_every_tokens: int = Field(
        8, ge=1, le=1000, description="A streamed request (\"stream\": true) of the GPT or HiFiGPT family gets its "
                                      "first final frames at once, then a message whenever at least this many more "
                                      "codes' frames (and at least as many as sent before) are final; one decode each.")
    unknown_text: Literal["warn", "reject"] = Field(
        "warn", description="A sentence far from every training caption of the model (bundles with a caption index): "
                            "'warn' answers 200 with a warning naming the segment, 'reject' answers 422 naming it.")

    @field_validator("cors_origins", "extra_model_dirs", "execution_providers", mode="before")
    @classmethod
    def _split_commas(cls, value: object) -> object:
        """Accept 'https://a.example, https://b.example' (or 'models/a,models/b') from the environment as well as
        a list."""
        if isinstance(value, str):
            return [item.strip() for item in value.split(",") if item.strip()]
        return value

    @field_validator("execution_providers", mode="after")
    @classmethod
    def _providers_once(cls, value: list[Provider]) -> list[Provider]:
        """'cuda,cuda' is 'cuda': each provider once, in its first place."""
        return list(dict.fromkeys(value))

    @property
    def execution(self) -> Execution:
        """The providers and the binding choice, as the bundle loader takes them."""
        from t2m.runtime.execution import Execution

        return Execution(tuple(self.execution_providers), self.io_binding, cuda_graphs=self.cuda_graphs,
                         graph_shapes=self.cuda_graph_shapes)

    @model_validator(mode="after")
    def _graphs_need_cuda(self) -> Settings:
        """CUDA graphs without the CUDA provider would quietly do nothing: refused, naming both settings."""
        if self.cuda_graphs and "cuda" not in self.execution_providers:
            raise ValueError("T2M_CUDA_GRAPHS=true needs T2M_EXECUTION_PROVIDERS=cuda (got "
                             f"{','.join(self.execution_providers)})")
        return self

    @property
    def model_dirs(self) -> list[Path]:
        """Every bundle to serve, the default first."""
        return [self.bundle_path, *self.extra_model_dirs]

    def for_bundle(self, directory: Path) -> Settings:
        """These settings with `directory` as the only bundle: what an engine factory is given for each model."""
        return self.model_copy(update={"bundle_path": directory, "extra_model_dirs": []})

    @field_validator("api_key", mode="after")
    @classmethod
    def _empty_key_is_none(cls, value: SecretStr | None) -> SecretStr | None:
        """T2M_API_KEY= (empty) means no key rather than the empty key."""
        if value is not None and not value.get_secret_value():
            return None
        return value
