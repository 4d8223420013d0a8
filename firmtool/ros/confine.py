"""Where the ROS 2 nodes may talk: a private network namespace holding only the loopback interface.

DDS finds its peers by multicast, on every interface, by default. Tests, benchmarks and CI must send
no packet beyond the machine's loopback, so every ROS process they start runs through
:func:`confined_command`: ``unshare --net`` gives the command a network namespace of its own, in which
``ip link set lo up`` brings up the only interface there is. Inside it a packet has nowhere to go but
``127.0.0.1``, whatever the middleware tries; on top of that :func:`environment` tells ROS and Fast DDS
to stay on the host (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, a private ``ROS_DOMAIN_ID``, and a
Fast DDS profile, :data:`FASTDDS_PROFILE`, of shared memory and UDP on ``127.0.0.1`` only, with
unicast discovery to ``127.0.0.1`` and no multicast locator). All the nodes of one test run inside one
namespace, so that they find each other.

This module imports nothing of ROS: the test helper, the benchmark and the CI step use it where the
ROS client library may be missing. On a real robot network none of this applies: see
docs/tutorials/ros.md.
"""

from __future__ import annotations

import os
import shlex
import shutil
from pathlib import Path

#: Fast DDS participant profile: shared memory (same host) and UDPv4 on 127.0.0.1 only; discovery by
#: unicast to 127.0.0.1 (the initial peers) and listening on 127.0.0.1 only, so that no multicast
#: locator is created (Fast DDS adds the default multicast ones only when no metatraffic locator is
#: given). Fast DDS 3 reads it from FASTDDS_DEFAULT_PROFILES_FILE (the older FASTRTPS_ name is
#: deprecated and warns).
FASTDDS_PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<dds xmlns="http://www.eprosima.com">
  <profiles>
    <transport_descriptors>
      <transport_descriptor>
        <transport_id>firmtool_shm</transport_id>
        <type>SHM</type>
      </transport_descriptor>
      <transport_descriptor>
        <transport_id>firmtool_loopback</transport_id>
        <type>UDPv4</type>
        <interfaceWhiteList>
          <address>127.0.0.1</address>
        </interfaceWhiteList>
      </transport_descriptor>
    </transport_descriptors>
    <participant profile_name="firmtool_loopback_only" is_default_profile="true">
      <rtps>
        <useBuiltinTransports>false</useBuiltinTransports>
        <userTransports>
          <transport_id>firmtool_shm</transport_id>
          <transport_id>firmtool_loopback</transport_id>
        </userTransports>
        <builtin>
          <metatrafficUnicastLocatorList>
            <locator><udpv4><address>127.0.0.1</address></udpv4></locator>
          </metatrafficUnicastLocatorList>
          <initialPeersList>
            <locator><udpv4><address>127.0.0.1</address></udpv4></locator>
          </initialPeersList>
        </builtin>
        <defaultUnicastLocatorList>
          <locator><udpv4><address>127.0.0.1</address></udpv4></locator>
        </defaultUnicastLocatorList>
      </rtps>
    </participant>
  </profiles>
</dds>
"""

#: the ROS domain of confined runs (0 is every robot's default; 0-101 are the ids Fast DDS maps to
#: ports without clashes); a test may pass its own to keep concurrent runs apart
DEFAULT_DOMAIN_ID = 77


def confinement_problem() -> str | None:
    """Why confined runs are impossible here (None: they are possible): ``unshare --net`` needs root
    (or user namespaces) and the ``unshare`` and ``ip`` programs."""
    for program in ("unshare", "ip"):
        if shutil.which(program) is None:
            return f"no '{program}' program (util-linux, iproute2)"
    if os.geteuid() != 0:
        return "not root: 'unshare --net' needs root to make a private network namespace"
    return None


def environment(folder: str | Path, domain_id: int = DEFAULT_DOMAIN_ID, base: dict | None = None) -> dict[str, str]:
    """The environment of a confined ROS process: ``base`` (default: this process's) with the ROS and
    Fast DDS settings of the module notes; the profile is written to ``folder``.

    Parameters
    ----------
    folder : where ``fastdds_loopback.xml`` is written (a test's temporary folder).
    domain_id : the ROS domain (0-101).
    base : the environment to extend (default ``os.environ``).

    Returns
    -------
    dict
        The environment, for ``subprocess.Popen(..., env=...)``.
    """
    if not 0 <= int(domain_id) <= 101:
        raise ValueError(f"domain_id: expected 0-101, found {domain_id}")
    profile = Path(folder) / "fastdds_loopback.xml"
    profile.write_text(FASTDDS_PROFILE)
    env = dict(os.environ if base is None else base)
    env.update({
        "ROS_DOMAIN_ID": str(int(domain_id)),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "ROS_STATIC_PEERS": "",
        "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp",
        "FASTDDS_DEFAULT_PROFILES_FILE": str(profile),
        # the profile's transports are used as written, not merged with rmw's defaults
        "RMW_FASTRTPS_USE_QOS_FROM_XML": "0",
        "ROS_LOG_DIR": str(Path(folder) / "ros_log"),
        "PYTHONUNBUFFERED": "1",
    })
    return env


def confined_command(argv: list[str]) -> list[str]:
    """``argv`` run in a new network namespace with only the loopback interface, up.

    Every process ``argv`` starts inherits the namespace: a driver that starts both nodes keeps them
    together, and away from every other interface.

    Examples
    --------
    >>> confined_command(["python", "-c", "print(1)"])[:2]
    ['unshare', '--net']
    """
    inner = "ip link set lo up && exec " + " ".join(shlex.quote(a) for a in argv)
    return ["unshare", "--net", "sh", "-c", inner]


def inside_private_namespace() -> bool:
    """Whether this process sees no network interface but the loopback (a confined run's check of
    itself before it starts any ROS node)."""
    try:  # /proc/net/dev is the namespace's own (/sys/class/net is the host's unless sysfs is remounted)
        lines = Path("/proc/net/dev").read_text().splitlines()[2:]
    except OSError:
        return False
    return {line.split(":")[0].strip() for line in lines} == {"lo"}


__all__ = ["DEFAULT_DOMAIN_ID", "FASTDDS_PROFILE", "confined_command", "confinement_problem", "environment",
           "inside_private_namespace"]
