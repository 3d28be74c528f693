"""The ``dcqn-zoo`` console script: :func:`sb3_dcqn.zoo.main` with the CampusNav ids registered.

:mod:`sb3_dcqn.zoo` works with any Gymnasium env and registers none; this entry point imports :mod:`campusnav_env`
first, so that ``dcqn-zoo train --algo dcqn --env CampusNav-v0`` finds the env (as ``--gym-packages campusnav_env``
would). ``train`` and ``enjoy`` on a CampusNav id use one torch thread unless ``--num-threads N`` is given: CampusNav's
networks are small, and more threads only contend for the cores (README's ``train`` command on CampusNav-v0, 30k
steps on 2 cores shared with other jobs: 913 s with torch's default two threads, 152 s with one).
"""

from __future__ import annotations

__all__ = ["main"]


def main(argv: list[str] | None = None) -> None:
    """Entry point of ``dcqn-zoo``: register the CampusNav ids, then run :func:`sb3_dcqn.zoo.main`."""
    from sb3_dcqn import zoo

    zoo.require_zoo(argv)  # before CampusNav's imports, when the zoo extra is missing: how to install it
    import campusnav_env  # noqa: F401  (registers the CampusNav ids with gymnasium)
    from campusnav_env.registration import ENV_IDS

    zoo.main(argv, single_thread_envs=tuple(ENV_IDS))


if __name__ == "__main__":
    main()
