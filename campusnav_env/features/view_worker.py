"""A worker process of the parallel view build: ``python -m campusnav_env.features.view_worker``.

Started by :func:`~campusnav_env.features.parallel_build.encode_views_in_workers`, which talks to it over its stdin
and stdout (:func:`~campusnav_env.features.parallel_build.serve_worker`). Being a module of the package, not a copy of
the parent's ``__main__``, it never runs the user's script again.
"""

from __future__ import annotations

import sys

from campusnav_env.features.parallel_build import serve_worker

if __name__ == "__main__":
    sys.exit(serve_worker())
