"""What a run leaves behind: the log's container and rows (logfile), live telemetry, and the
replay of a log through the core the robot ran."""
