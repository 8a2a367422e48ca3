"""Host-side flashing: images, plans, per-node sessions, batch orchestration."""
