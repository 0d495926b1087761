import sys

from tipbot_fw.guard.safety import EXIT_INTERRUPT, SignalGuard, Terminated


def _main():
    # The signal handlers come first, before the imports that take seconds on the brick (numpy),
    # and long before any device is touched: a signal at any moment of the start ends the
    # process with one line and, once devices are open, with the motors stopped.
    guard = SignalGuard().install()
    try:
        # numpy first, without the subpackages a run never loads (tipbot_fw.lean_numpy)
        from tipbot_fw.lean_numpy import import_numpy
        import_numpy(may_retry=lambda: guard.raised is None)
        from tipbot_fw.cli import main
    except (KeyboardInterrupt, Terminated, ImportError) as e:
        if isinstance(e, ImportError):
            if guard.raised is None:
                raise
            # a C extension's import (numpy's) turns the signal's exception into its ImportError
            e = guard.raised
        sys.stderr.write('tipbot: {} while starting: nothing was started\n'.format(
            'interrupted' if isinstance(e, KeyboardInterrupt) else e))
        return EXIT_INTERRUPT if isinstance(e, KeyboardInterrupt) else e.exit_code
    return main(guard=guard)


sys.exit(_main())
