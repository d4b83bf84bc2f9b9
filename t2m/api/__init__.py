"""The API's request and answer models (pydantic, no FastAPI): the HTTP service validates and publishes them as
OpenAPI, and the CLI validates `t2m generate` and `t2m edit` with the same ones."""
