"""``jnds serve`` and its Python client; the wire protocol is ``PROTOCOL``."""

from ..errors import ServerError
from .client import Client, ClientStream
from .server import PROTOCOL, FrameServer, ServeConfig, make_http_server, serve

__all__ = [
    "Client",
    "ClientStream",
    "ServerError",
    "PROTOCOL",
    "FrameServer",
    "ServeConfig",
    "make_http_server",
    "serve",
]
