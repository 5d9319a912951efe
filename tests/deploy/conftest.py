"""Fixtures for the deployment tests: fake notify sockets (see notify_socket.py)."""

from .notify_socket import abstract_notify_socket, notify_socket

__all__ = ["abstract_notify_socket", "notify_socket"]
