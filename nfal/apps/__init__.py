"""The applications: what assembles the layers below into the product (the Fig. 7 loop, sweep kinds, the rig
emulator and the rig it plays, identification, builds, host checks, the paper's reproduction) and the figures they
draw. They may import every layer below; the command line (:mod:`nfal.cli`) calls them."""
