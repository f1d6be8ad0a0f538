"""Plain DDS topics in ``-m dds``: types and topics that are not ROS ones, created on the DDS domain
under exactly the client's names and carrying its CDR (``entities``), through a bridge to the Fast
DDS of the ROS in use compiled on first use (``build``, ``_plaindds.cpp``)."""
