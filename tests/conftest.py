"""Suite-wide pytest options."""


def pytest_addoption(parser):
    group = parser.getgroup("hardware", "tests against real devices (skipped unless --hardware)")
    group.addoption("--hardware", action="store_true", default=False, help="run tests that need real devices")
    group.addoption("--lms-port", default=None, help="serial port of a SICK LMS2xx for --hardware tests")
    group.addoption("--tilt-port", default=None, help="serial port of a PowerCube for --hardware tests")


def pytest_collection_modifyitems(config, items):
    """Files holding a ``slow`` test first, those with the fewest tests first (their tests are the
    longest single items), then the rest in collection order.

    Under ``--dist loadfile`` with ``--no-loadscope-reorder`` (pyproject.toml) each worker takes
    the next file of this order when it runs dry, so the long files start early and overlap the
    many short ones. xdist's own order (the most tests first) put the one-test wheel build and
    the few-test end-to-end files last, where a worker ran them alone while the other idled.
    """
    files: dict[str, list] = {}
    for item in items:
        files.setdefault(item.nodeid.split("::", 1)[0], []).append(item)

    def rank(path: str) -> tuple[int, int]:
        tests = files[path]
        if any(test.get_closest_marker("slow") for test in tests):
            return 0, len(tests)
        return 1, 0

    items[:] = [item for path in sorted(files, key=rank) for item in files[path]]
