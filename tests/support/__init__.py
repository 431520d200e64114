"""Shared test support: every helper more than one test file uses, by concern (the fixtures
live in tests/conftest.py). A test file imports ``support.<module>``, never another test file
(tests/repo/test_tests_layout.py); tests/ is on pytest's ``pythonpath`` (pyproject.toml).

Processes and the bus: ``spawn`` (subprocesses, free ports, a child's environment), ``routers``
(``formation router`` on loopback), ``procguard`` (nothing a test starts outlives it),
``bus_watch`` (record and strictly decode a key expression), ``bus_inbox`` (received samples
with waits), ``bus_samples`` (one valid message per type), ``async_wait``.

Nodes and runs: ``agent_io`` (drive one agent), ``coordinator_io`` (drive a coordinator),
``lockstep_equality`` (lockstep over Zenoh against the in-process simulator), ``up_runs``
(whole ``formation up`` runs), ``run_traffic`` (an in-process run as bus traffic, for the
collector), ``record_stream`` (a synthetic stream and the recorder fed with it), ``fault_fleet``
(the realtime fleet faults are injected into), ``estop_checks``,
``foxglove_fleet`` (traffic for the live view, its protobuf frames, a Teleop panel's publishes),
``operator_bus`` (perfect followers of a coordinator under test, leader jumps), ``yard`` (the
replanning tests' scenario), ``json_schema``.

Cores: ``firmware_cases`` (the firmware's config, hostile numbers, one step),
``safety_cases`` and ``safety_runs`` (the safety filter's robot and closed loops),
``synthetic_logs`` (a run log for figures and metrics).

Hosts and devices: ``notify_socket`` (a systemd notify socket), ``netns``, ``deploy_hosts``,
``deploy_world``, ``small_fs``, ``roboclaw_emulator``, ``ros2_base``, ``ros2_reference``,
``ros2_sdk_client``. Closed loops: ``carry_runs`` (a spare carried through a formation).
"""
