"""Running untrusted programs (decoders under test): one concern, below the harness.

* :mod:`.sandbox` — one invocation: argv (never a shell), its own folder, limits, bubblewrap;
* :mod:`.cgroups` — the whole process tree's memory and process-count limits;
* :mod:`.launcher` — the Python launcher that applies the limits where ``prlimit`` is missing;
* :mod:`.endings` — how a process ended (the one classifier of ``run``, ``certify``, ``fuzz``);
* :mod:`.forkserver` (Python) and ``forkserver.c`` — a fork server inside one sandbox;
  :mod:`.forkserver_build` compiles the C one; :mod:`.forkclient` drives either;
* :mod:`.persistent` — the persistent protocol (one process, many inputs).
"""
