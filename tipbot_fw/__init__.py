"""tipbot firmware: balances the three-link EV3 robot on the brick (Python 3.5, numpy 1.12)."""

__version__ = '0.2.0'
