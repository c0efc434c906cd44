"""``jnds serve`` and its Python client; the wire protocol is ``PROTOCOL``."""
from .client import Client, ClientStream, ServerError
from .server import PROTOCOL, FrameServer, ServeConfig, make_http_server, serve

__all__ = ["Client", "ClientStream", "ServerError", "PROTOCOL", "FrameServer", "ServeConfig",
           "make_http_server", "serve"]
