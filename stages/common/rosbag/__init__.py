"""ROS 2 bags: the mapping file beside a bag (``mapping``) and the messages read and written (``messages``)."""
