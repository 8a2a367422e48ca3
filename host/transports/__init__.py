"""Transport backends; each is imported only when a URL needs it (see :mod:`host.transport`)."""
