"""Evaluation suite: the paper's experiments from a run directory (``ursa eval ...``).

One module per experiment (``diversity``, ``damage``, ``velocity``, ``embedding``, ``curves``),
shared loading of a run (``loading``), skill execution (``rollout``), grid coverage
(``coverage``). Pure core code: no zenoh, FastAPI or viser. See docs/eval.md.
"""
