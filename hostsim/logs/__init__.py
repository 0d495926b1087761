"""Robot logs on the host: replay of balance runs (replay), motor identification (identify),
export to CSV (export) and live telemetry (watch)."""
import os

from tipbot_fw import logfile


def read_log(path, error):
    """(header, rows, column names) of a tipbot log (tipbot_fw.logfile); error('<path>: ...')
    when it is missing, unreadable or corrupt."""
    if not os.path.isfile(path):
        raise error("%s: no such log file" % path)
    try:
        header, rows = logfile.read_log(path)
    except logfile.LogFormatError as e:
        raise error(str(e))
    except OSError as e:
        raise error("%s: cannot read: %s" % (path, e))
    names = [c.get("name") if isinstance(c, dict) else c for c in header.get("columns", [])]
    return header, rows, names
