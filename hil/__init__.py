"""Hardware in the loop: the rig protocol (docs/protocol.md), the serial link, the rig emulator."""
