"""Deployment on a shop PC: the systemd unit, udev rules, example configuration, installer,
and the sd_notify client the daemon uses for readiness and the watchdog.

The files themselves live in the repository's ``systemd/`` directory (``templates`` here
is a link to it), so the installer and the tests render exactly what is documented there.
"""

from .install import (
    InstallOptions,
    UninstallOptions,
    add_install_arguments,
    add_uninstall_arguments,
    install_service,
    run_install,
    run_uninstall,
    uninstall_service,
)
from .render import BoardIds, DeployError
from .sdnotify import SdNotifier

__all__ = [
    "BoardIds",
    "DeployError",
    "InstallOptions",
    "SdNotifier",
    "UninstallOptions",
    "add_install_arguments",
    "add_uninstall_arguments",
    "install_service",
    "run_install",
    "run_uninstall",
    "uninstall_service",
]
