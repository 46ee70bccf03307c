//! TV-L1 optical flow. (Being written.)
