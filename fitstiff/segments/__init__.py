"""A log's structure: reversals, loops, pauses and regions (segmentation), reversal-preserving
denoising, and the summary `fitstiff inspect` prints."""
