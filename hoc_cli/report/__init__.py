"""What ``hoc plan`` and ``hoc batch`` both report and write, so that neither front end imports the other.

- ``summary``: ``plan_report`` — a solved ``Plan`` as its JSON summary, ``Status`` and ``converged``;
- ``status``: ``Status``, the one status enum, and ``MESSAGES``, the words both reporters use;
- ``limits``, ``collision``, ``goals``: each task section's checks before the solve and summary keys;
- ``prepare``: a task made ready to solve (robot, states, limits, collision, problem) and its report after;
- ``inputs``: the checks of outputs and starts before any work;
- ``outputs``, ``files``, ``locks``: the plan at the output rate, written atomically;
- ``console``, ``jsonio``, ``table``: lines on standard error, strict JSON, the summary table;
- ``workload``: the expected cost of a run and the heartbeat while it runs.

This package imports neither ``commands/`` nor ``batch/`` (``tests/test_layers.py``); its modules
are imported where used, so ``import hoc_cli.report`` loads nothing else.
"""
