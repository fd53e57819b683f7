"""What people and scripts run: the ``ktbt`` command line (``cli``), the peer commands
(``peer``), the tour and demo vocabulary (``demo``), the fuzzer (``fuzz``), the fleet monitor
(``monitor``) and the fleet tool (``fleet``). Nothing below imports this package.
"""
