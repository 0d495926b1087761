"""Robot logs on the host: replay of balance runs (replay), motor identification (identify),
export to CSV (export) and live telemetry (watch)."""
import os

from tipbot_fw import fields
from tipbot_fw.record import logfile


def read_log(path, error):
    """(header, rows, column names) of a tipbot log (tipbot_fw.record.logfile); error('<path>: ...')
    when it is missing, unreadable or corrupt."""
    if not os.path.isfile(path):
        raise error("%s: no such log file" % path)
    try:
        header, rows = logfile.read_log(path)
    except logfile.LogFormatError as e:
        raise error(str(e))
    except OSError as e:
        raise error("%s: cannot read: %s" % (path, e))
    f = fields.Fields(path, error)
    cols = header.get("columns")
    if not isinstance(cols, list) or not all(isinstance(c, dict) and isinstance(c.get("name"), str) for c in cols):
        f.fail("columns", "must be a list of {name, unit} objects")
    for key, checker in (("kind", fields.string), ("versions", fields.obj), ("gains", fields.obj),
                         ("config", fields.obj), ("calibration", fields.obj), ("stop_message", fields.string),
                         ("stop_reason", fields.string)):
        if key in header:
            f.check(key, header[key], checker)
    versions = header.get("versions", {})
    for key in sorted(versions):
        f.check("versions." + key, versions[key], fields.string)
    return header, rows, [c["name"] for c in cols]
