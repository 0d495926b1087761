"""What keeps a run safe: why it stops and with which exit code (safety), what the hardware can
report (plausibility), the page shared with the supervisor (heartbeat), real-time scheduling.
Standard library only where the supervisor imports it (it starts without numpy)."""
