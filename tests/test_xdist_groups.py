"""``make test``'s promise (tests/conftest.py): tests that share a module-scoped
fixture (a server, a cluster, a module's fits) run on one pytest-xdist worker, so
the fixture is set up once. pytest 9.2 with pytest-xdist 3.8 silently broke it
(xdist's group suffix on the nodeid no longer took), and every such fixture was
set up on each worker; this test fails instead."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.contract

GROUP = "tests/test_xdist_groups.py"


@pytest.fixture(scope="module")
def shared():
    return object()


def test_a_test_with_a_module_fixture_is_in_its_files_group(shared, request):
    mark = request.node.get_closest_marker("xdist_group")
    assert mark is not None and mark.args == (GROUP,)
    config = request.config
    if hasattr(config, "workerinput") and getattr(config.option, "loadgroup", False):
        # what pytest-xdist's loadgroup scheduler groups by
        assert request.node.nodeid.endswith(f"@{GROUP}"), request.node.nodeid
