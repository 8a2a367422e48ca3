"""``hil-fuzz``'s library: the targets, the steps a campaign sends, the oracles that judge
them and the campaign with its shrinking and replay."""
