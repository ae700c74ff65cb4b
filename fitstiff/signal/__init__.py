"""Array-level signal tools that know no log: the noise floor of a channel, gross spikes, the
monotone runs of a displacement."""
