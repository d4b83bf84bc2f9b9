"""Prometheus metrics of one app instance (its own registry, so several apps in one process do not collide).

t2m_requests_total{route,method,status}, t2m_request_duration_seconds{route} (histogram; a streamed answer counts
until its last byte), and per served model t2m_tokens_generated_total{model}, t2m_segments_generated_total{model},
t2m_queue_depth{model}, t2m_in_flight{model}, t2m_time_to_first_frame_seconds{model} (histogram of streamed
requests: from the request to its first frames being ready to send), t2m_model_info{name,version} (model = the
manifest name, as in the request's `model` field).
"""
from __future__ import annotations

import time
from collections.abc import Callable

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, Info
from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = ["MetricsMiddleware", "ServiceMetrics"]

LATENCY_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 120.0)
FIRST_FRAME_BUCKETS = (0.005, 0.01, 0.015, 0.02, 0.025, 0.03, 0.04, 0.05, 0.075, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0,
                       30.0, 60.0)   # fine around the 30 ms goal


class ServiceMetrics:
    """The collectors; each model's queue depth and in-flight are read from its batcher when Prometheus scrapes."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter("t2m_requests", "HTTP requests by route, method and status code",
                                ["route", "method", "status"], registry=self.registry)
        self.latency = Histogram("t2m_request_duration_seconds", "HTTP request latency by route", ["route"],
                                 buckets=LATENCY_BUCKETS, registry=self.registry)
        self.tokens = Counter("t2m_tokens_generated", "Motion code tokens generated, by model", ["model"],
                              registry=self.registry)
        self.segments = Counter("t2m_segments_generated", "Sentences turned into motion, by model", ["model"],
                                registry=self.registry)
        self.queue_depth = Gauge("t2m_queue_depth", "Requests waiting for an engine worker, by model", ["model"],
                                 registry=self.registry)
        self.in_flight = Gauge("t2m_in_flight", "Requests a worker holds (in its batch window or generating), by model",
                               ["model"],
                               registry=self.registry)
        self.first_frame = Histogram("t2m_time_to_first_frame_seconds",
                                     "Streamed requests: seconds from the request to its first frames, by model",
                                     ["model"], buckets=FIRST_FRAME_BUCKETS, registry=self.registry)
        self.model = Info("t2m_model", "The loaded model bundles (one series each)", ["name", "version"],
                          registry=self.registry)

    def add_model(self, name: str, version: str, queue_depth: Callable[[], float],
                  in_flight: Callable[[], float]) -> None:
        """Publish a loaded model: its info series, its queue gauges, and its counters at 0 before any request."""
        self.model.labels(name, version).info({})
        self.queue_depth.labels(name).set_function(queue_depth)
        self.in_flight.labels(name).set_function(in_flight)
        self.tokens.labels(name)
        self.segments.labels(name)
        self.first_frame.labels(name)

    def count_generation(self, model: str, tokens: int, segments: int) -> None:
        self.tokens.labels(model).inc(tokens)
        self.segments.labels(model).inc(segments)


class MetricsMiddleware:
    """Counts every HTTP request by its route template (not the raw path, to keep label cardinality bounded)."""

    def __init__(self, app: ASGIApp, metrics: ServiceMetrics, known_paths: Callable[[], set[str]]) -> None:
        self.app = app
        self.metrics = metrics
        self.known_paths = known_paths

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        status = 500
        started = time.perf_counter()

        async def send_and_record(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_and_record)
        finally:
            route = scope.get("route")
            path = getattr(route, "path", None) or scope.get("path", "")
            label = path if path in self.known_paths() else "unmatched"
            self.metrics.requests.labels(label, scope.get("method", ""), str(status)).inc()
            self.metrics.latency.labels(label).observe(time.perf_counter() - started)
