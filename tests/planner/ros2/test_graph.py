"""rmw_zenoh's names against the examples of its design document.

The expected strings are copied from ros2/rmw_zenoh ``docs/design.md`` (rolling, commit
99a6a2bd10b949052f4f12c5854825dc005e95a5), sections "Topic and Service name mapping to Zenoh
key expressions" ("The format of key expressions for topics and services is:
`<domain_id>/<fully_qualified_name>/<type_name>/<type_hash>`") and "Graph Cache" ("The format
of a liveliness token for a publisher ...: `@ros2_lv/<domain_id>/<session_id>/<node_id>/
<entity_id>/<entity_kind>/<mangled_enclave>/<mangled_namespace>/<node_name>/
<mangled_qualified_name>/<type_name>/<type_hash>/<qos>`").
"""

from __future__ import annotations

import pytest

from planner.ros2.graph import (
    LATCHED,
    Node,
    Qos,
    attachment,
    dds_type_name,
    gid,
    mangle,
    parse_attachment,
    topic_key,
)

#: std_msgs/msg/String's type hash as printed in the design document's examples
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


def test_topic_keys_match_the_design_document_examples() -> None:
    assert topic_key(0, "/chatter", "std_msgs/msg/String", STRING_HASH) == (
        "0/chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )
    assert topic_key(0, "/robot1/chatter", "std_msgs/msg/String", STRING_HASH) == (
        "0/robot1/chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )


def test_node_and_publisher_tokens_match_the_design_document_examples() -> None:
    listener = Node(2, "aac3178e146ba6f1fc6e6a4085e77f21", "listener")
    assert listener.token() == "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    talker = Node(2, "8b20917502ee955ac4476e0266340d5c", "talker")
    # the talker's publisher: keep-last 7, otherwise rmw_zenoh's defaults
    token = talker.publisher_token(10, "chatter", "std_msgs/msg/String", STRING_HASH, Qos(7))
    assert token == (
        "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        "std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,"
    )


def test_qos_text_follows_qos_to_keyexpr() -> None:
    # the design document's subscription example has depth 10: "::,10:,:,:,,"
    assert Qos(10).keyexpr() == "::,10:,:,:,,"
    # transient local (rmw_qos_durability_policy_e 1), depth 1: tf2's /tf_static profile
    assert LATCHED.keyexpr() == ":1:,1:,:,:,,"
    # rmw_zenoh's own default depth (42, qos.cpp) is left empty
    assert Qos(42).keyexpr() == "::,:,:,:,,"


def test_names_are_mangled_and_typed_as_in_dds() -> None:
    assert mangle("/robot1/chatter") == "%robot1%chatter"
    assert mangle("/") == "%"
    assert dds_type_name("sensor_msgs/msg/JointState") == "sensor_msgs::msg::dds_::JointState_"
    ns = Node(0, "ab", "n", namespace="/cell")
    assert "/%/%cell/n/%cell%tf/" in ns.publisher_token(1, "tf", "tf2_msgs/msg/TFMessage", "H")
    with pytest.raises(ValueError, match="pkg/msg/Name"):
        dds_type_name("JointState")
    with pytest.raises(ValueError, match="valid ROS name"):
        topic_key(0, "/a//b", "std_msgs/msg/String", STRING_HASH)


def test_attachment_layout() -> None:
    g = gid("@ros2_lv/0/x/0/1/MP/%/%/n/%tf/t/h/::,:,:,:,,")
    data = attachment(5, 1_700_000_000_123_456_789, g)
    # 8 bytes seq LE, 8 bytes ns LE, 1 byte GID length, 16 bytes GID (design.md "Publishers")
    assert len(data) == 33
    assert data[:8] == (5).to_bytes(8, "little")
    assert data[8:16] == (1_700_000_000_123_456_789).to_bytes(8, "little")
    assert data[16] == 16
    assert parse_attachment(data) == (5, 1_700_000_000_123_456_789, g)
    with pytest.raises(ValueError, match="16 bytes"):
        attachment(1, 0, b"short")


def test_subscription_tokens_have_kind_ms() -> None:
    # design.md: "`MS` for a message subscription"; the listener example's token
    listener = Node(2, "aac3178e146ba6f1fc6e6a4085e77f21", "listener")
    assert listener.subscription_token(
        10, "chatter", "std_msgs/msg/String", STRING_HASH, Qos(10)
    ) == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
        "std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,10:,:,:,,"
    )


def test_gids_are_the_xxh3_128_of_the_token_as_rmw_zenoh_lays_them_out() -> None:
    """rmw_zenoh's Entity: XXH3-128 of the liveliness key expression, low 64 bits then high
    64 bits in memory (little-endian) order. The empty input's XXH3-128 is the xxHash
    project's published check value 99aa06d3014798d8 6001c324468d497f (high, low)."""
    assert gid("") == bytes.fromhex("7f498d4624c30160d8984701d306aa99")
    token = "@ros2_lv/0/x/0/1/MP/%/%/n/%tf/t/h/::,:,:,:,,"
    assert gid(token) != gid(token + "x") and len(gid(token)) == 16
