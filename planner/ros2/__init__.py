"""ROS 2 without ROS: beamrelay's state on rmw_zenoh's key expressions, and ROS 2 channels
in recordings. Messages, CDR and type hashes come from rosbags (:mod:`planner.ros2.messages`);
rmw_zenoh's names from its design document (:mod:`planner.ros2.graph`); the TF tree and
markers of the cell (:mod:`planner.ros2.cell`); the bridge node (:mod:`planner.ros2.bridge`);
recording channels (:mod:`planner.ros2.recording`)."""
