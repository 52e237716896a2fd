"""Errors of the mock vehicle endpoint.

Exception tree::

    MockError(Exception)                  anything the mock fleet cannot do
      MockConfigError(MockError, ValueError)  a bad configuration value (names the field)
      MockStartError(MockError, OSError)      a socket could not be bound (names host:port)

Protocol problems caused by a client (bad mission items, unknown commands,
refused mode switches) are never exceptions: they are answered on the link
with the MAVLink result a PX4 vehicle would send.
"""

from __future__ import annotations


class MockError(Exception):
    """Base class of the mock endpoint's errors."""


class MockConfigError(MockError, ValueError):
    """A configuration value of the mock fleet is invalid; the message names it."""


class MockStartError(MockError, OSError):
    """A vehicle could not bind its UDP port; the message names host and port."""
