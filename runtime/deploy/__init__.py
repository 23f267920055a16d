"""A robot deployment kit: `mrta init-robot` (:mod:`runtime.deploy.init_robot`), the systemd unit and the udev rules
shipped beside it (docs/deploy.md)."""
