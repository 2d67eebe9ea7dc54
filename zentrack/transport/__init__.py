"""Transport: the wire codec, key expressions, Zenoh configuration and sessions, liveliness, the router."""
