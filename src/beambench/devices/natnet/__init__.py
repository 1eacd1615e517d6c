"""OptiTrack Motive over NatNet 3.0–4.1: the codec (``protocol``), the client and mocap stream (``client``),
many frames at once (``block``), and packet captures (``pcap``, ``capture``)."""
