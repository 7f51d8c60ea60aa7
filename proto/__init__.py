"""Wire format of URSA: protobuf schemas (``ursa.proto``), generated code, codec and topics."""
