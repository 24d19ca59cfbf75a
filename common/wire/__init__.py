"""The wire: Zenoh sessions, bounded inboxes, and the authentication of every message."""
