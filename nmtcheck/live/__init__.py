"""Live checking: nmtcheck monitor, check --follow and the python-can Listener."""
