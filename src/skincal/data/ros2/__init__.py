"""ROS 2 on a live graph without a ROS install (the ``cyclonedds`` binding, extra ``skincal[ros2]``):
:mod:`~skincal.data.ros2.messages` the ROS 2 message types as IDL structs, :mod:`~skincal.data.ros2.qos`
ROS 2's QoS profiles, :mod:`~skincal.data.ros2.participant` the one participant factory (loopback,
multicast off by default), :mod:`~skincal.data.ros2.decode` received samples decoded one by one
(malformed or oversized: counted and dropped). Bags are :mod:`skincal.data.ros`'s."""
