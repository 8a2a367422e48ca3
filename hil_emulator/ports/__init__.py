"""The host's ports: ptys (``pty_port``, ``port_reader``), the SLCAN adapter, the links that
join them to a rig (``host_links``, ``host_side``, ``link_tap``) and the link directory."""
