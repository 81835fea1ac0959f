"""The case files and the harness are imported by ``test_battery.py`` only (each case file
registers its cases once); pytest must not import them a second time for doctests."""

collect_ignore_glob = ["cases_*.py", "harness.py"]
