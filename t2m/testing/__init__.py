"""What the tests and the benchmarks both need, in the package so that neither imports the other: random weights in
the exact formats of released files that no family owns (OpenAI's CLIP archive). A family's own random releases
live in its folder (`*_release.py`)."""
