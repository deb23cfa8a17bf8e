"""Suite-wide pytest options."""


def pytest_addoption(parser):
    group = parser.getgroup("hardware", "tests against real devices (skipped unless --hardware)")
    group.addoption("--hardware", action="store_true", default=False, help="run tests that need real devices")
    group.addoption("--lms-port", default=None, help="serial port of a SICK LMS2xx for --hardware tests")
    group.addoption("--tilt-port", default=None, help="serial port of a PowerCube for --hardware tests")
