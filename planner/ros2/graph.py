"""rmw_zenoh's names: data key expressions, liveliness tokens, QoS text and the attachment.

Follows ``docs/design.md`` of ros2/rmw_zenoh ("Topic and Service name mapping to Zenoh key
expressions", "Graph Cache", "Publishers") and ``qos_to_keyexpr`` in its
``rmw_zenoh_cpp/src/detail/liveliness_utils.cpp`` (defaults from ``qos.cpp``: reliable,
volatile, keep-last 42, infinite durations):

- data: ``<domain_id>/<fully_qualified_name>/<type_name>/<type_hash>``, the name without its
  leading ``/`` (``0/robot1/chatter/std_msgs::msg::dds_::String_/RIHS01_...``);
- node token: ``@ros2_lv/<domain_id>/<session_id>/<node_id>/<node_id>/NN/<mangled_enclave>/
  <mangled_namespace>/<node_name>``;
- publisher token: ``@ros2_lv/<domain_id>/<session_id>/<node_id>/<entity_id>/MP/
  <mangled_enclave>/<mangled_namespace>/<node_name>/<mangled_qualified_name>/<type_name>/
  <type_hash>/<qos>`` (``MS`` for a subscription), a mangled name having every ``/``
  replaced by ``%`` (``%`` alone when empty);
- every sample carries an attachment: sequence number (int64 LE), source timestamp (ns
  since the UNIX epoch, int64 LE), the GID length (one byte, 16) and the 16-byte GID.

Pure string and byte functions: no Zenoh, no ROS.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

ADMIN_SPACE = "@ros2_lv"
GID_LENGTH = 16
#: rmw_zenoh's default QoS (``qos.cpp``): a field equal to it is left empty in the token
DEFAULT_DEPTH = 42


class Durability(IntEnum):
    """``rmw_qos_durability_policy_e`` values (the numbers written in the QoS text)."""

    TRANSIENT_LOCAL = 1
    VOLATILE = 2


@dataclass(frozen=True)
class Qos:
    """The QoS a publisher declares: reliable, keep-last ``depth``, ``durability``."""

    depth: int = 10
    durability: Durability = Durability.VOLATILE

    def keyexpr(self) -> str:
        """rmw_zenoh's compact text (``qos_to_keyexpr``): ``reliability:durability:
        history,depth:deadline:lifespan:liveliness``, each field empty when it equals the
        default (reliable, volatile, keep-last 42, infinite durations, automatic)."""
        durability = "" if self.durability is Durability.VOLATILE else str(int(self.durability))
        depth = "" if self.depth == DEFAULT_DEPTH else str(self.depth)
        return f":{durability}:,{depth}:,:,:,,"


VOLATILE = Qos()
#: what tf2 uses on /tf_static: transient local, depth 1
LATCHED = Qos(depth=1, durability=Durability.TRANSIENT_LOCAL)


def dds_type_name(ros_type: str) -> str:
    """``pkg/msg/Name`` as declared in DDS: ``pkg::msg::dds_::Name_``."""
    pkg, kind, name = check_type(ros_type)
    return f"{pkg}::{kind}::dds_::{name}_"


def check_type(ros_type: str) -> tuple[str, str, str]:
    parts = ros_type.split("/")
    if len(parts) != 3 or not all(parts) or parts[1] not in ("msg", "srv"):
        raise ValueError(f"ROS type {ros_type!r} is not of the form pkg/msg/Name")
    return parts[0], parts[1], parts[2]


def fully_qualified(name: str, namespace: str = "/") -> str:
    """A topic name made absolute in ``namespace`` (``chatter`` in ``/robot1`` ->
    ``/robot1/chatter``); an absolute name is kept."""
    if not name or name.endswith("/") or "//" in name:
        raise ValueError(f"topic name {name!r} is not a valid ROS name")
    if name.startswith("/"):
        return name
    return f"{namespace.rstrip('/')}/{name}"


def mangle(name: str) -> str:
    """A name with every ``/`` replaced by ``%``; ``%`` for an empty name or ``/``."""
    return name.replace("/", "%") if name not in ("", "/") else "%"


def topic_key(domain: int, topic: str, ros_type: str, type_hash: str) -> str:
    """The data key expression of ``topic`` (fully qualified) of type ``ros_type``."""
    return f"{domain}/{fully_qualified(topic).lstrip('/')}/{dds_type_name(ros_type)}/{type_hash}"


@dataclass(frozen=True)
class Node:
    """A ROS node as rmw_zenoh's graph sees it."""

    domain: int
    session_id: str
    name: str
    namespace: str = "/"
    node_id: int = 0
    enclave: str = ""

    def _prefix(self, entity_id: int, kind: str) -> str:
        return (
            f"{ADMIN_SPACE}/{self.domain}/{self.session_id}/{self.node_id}/{entity_id}/{kind}/"
            f"{mangle(self.enclave)}/{mangle(self.namespace)}/{self.name}"
        )

    def token(self) -> str:
        """The node's liveliness token (entity kind ``NN``)."""
        return self._prefix(self.node_id, "NN")

    def publisher_token(
        self, entity_id: int, topic: str, ros_type: str, type_hash: str, qos: Qos = VOLATILE
    ) -> str:
        """The liveliness token of a publisher (entity kind ``MP``) of this node."""
        return self._endpoint_token("MP", entity_id, topic, ros_type, type_hash, qos)

    def subscription_token(
        self, entity_id: int, topic: str, ros_type: str, type_hash: str, qos: Qos = VOLATILE
    ) -> str:
        """The liveliness token of a subscription (entity kind ``MS``) of this node."""
        return self._endpoint_token("MS", entity_id, topic, ros_type, type_hash, qos)

    def _endpoint_token(
        self, kind: str, entity_id: int, topic: str, ros_type: str, type_hash: str, qos: Qos
    ) -> str:
        fq = fully_qualified(topic, self.namespace)
        return (
            f"{self._prefix(entity_id, kind)}/{mangle(fq)}/{dds_type_name(ros_type)}/"
            f"{type_hash}/{qos.keyexpr()}"
        )


def gid(token: str) -> bytes:
    """The 16-byte GID of the entity whose liveliness token is ``token``, as rmw_zenoh
    makes it (``rmw_zenoh_cpp/src/detail/liveliness_utils.cpp``, ``Entity``): the XXH3-128
    hash of the token's key expression, its low 64 bits then its high 64 bits, each in the
    machine's (little-endian) byte order."""
    import xxhash

    return int(xxhash.xxh3_128_intdigest(token.encode())).to_bytes(GID_LENGTH, "little")


def attachment(seq: int, stamp_ns: int, publisher_gid: bytes) -> bytes:
    """The attachment of one sample: seq (int64 LE), source time (ns, int64 LE), GID length
    (one byte) and the GID."""
    if len(publisher_gid) != GID_LENGTH:
        raise ValueError(f"a GID has {GID_LENGTH} bytes, got {len(publisher_gid)}")
    return struct.pack("<qqB", seq, stamp_ns, GID_LENGTH) + publisher_gid


def parse_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(seq, source time in ns, GID) of an attachment written by :func:`attachment`."""
    if len(data) != 17 + GID_LENGTH:
        raise ValueError(f"an rmw_zenoh attachment has {17 + GID_LENGTH} bytes, got {len(data)}")
    seq, stamp, n = struct.unpack_from("<qqB", data)
    return seq, stamp, bytes(data[17 : 17 + n])
