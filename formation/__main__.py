import os

if os.environ.get("FORMATION_PARENT_PID"):  # a child of `formation up`: it dies with it
    from runtime.lifecycle import bind_to_parent

    bind_to_parent()

from formation.cli import main

raise SystemExit(main())
