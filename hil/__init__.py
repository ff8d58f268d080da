"""Hardware in the loop, the host's and the rig's common ground: the rig protocol (docs/protocol.md), the
serial link, the rig's firmware, ports and fault injection. The emulator that plays a rig is an application
(:mod:`nfal.apps.rig_emulator`, :mod:`nfal.apps.rig_model`)."""
