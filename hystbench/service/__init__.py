"""The bench daemon as a service: the process (``daemon``: signals, reload, the watchdog), its
configuration (``daemon_config``: the daemon file's schema, loader and checks), one configuration
running (``service``: sweeps, commands, faults, restarts), the source it builds (``source_config``),
its log (``service_log``, ``retention``), one daemon per bench (``instance``), systemd's notify
protocol (``sd_notify``), and the client side of ``hystbench ctl`` (``control``).

It runs the live chain and may import it (``hystbench.acquisition``: ring, sources, stages, pipeline,
zenoh bus, the command vocabulary) and what lies below it (the compensator, drivers, formats, the
vocabulary); the live chain never imports the service.  Inside, imports point down: daemon (and,
beside it, the ctl client) > service > source_config > daemon_config, service_log > instance,
retention, sd_notify (the ``service-layers`` contract in .importlinter)."""
