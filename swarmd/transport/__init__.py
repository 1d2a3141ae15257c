"""Channels the daemon broadcasts on: UDP multicast, XBee (digi-xbee), serial radios."""
