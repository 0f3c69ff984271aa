"""The network lab: the corridor's hosts in network namespaces, faults on their links (``deploy/netlab``).

``plan`` (pure): the address plan of a lab. ``net`` (root): namespaces, veth links, iptables and tc rules,
and their clean-up. ``lab``: the ``iea up`` topology with each role on its own host. ``schedule`` (pure): the
fault rows and their judging. ``rows``: one fault row run on a lab. ``scale``: corridors x RSUs of synthetic
object lists across namespaces.
"""
