// What a recorded sweep can be: the ranges every value of a dataset is checked against (the reader
// before it holds or reads anything more, the writer before it writes), and how much the reader
// reads. One place for them: the daemon's SWEEP and its recorder take theirs from here, and the
// stage's own keys (masses, stroke, stiffness) come from the stage table (model/stage.h).
#pragma once

#include <cstddef>

#include "model/range.h"

namespace idm::recording {

// A triangle's frequency, Hz: what a drive can play (the daemon's control.min_freq_hz and
// max_freq_hz take this range).
inline constexpr model::Range kFreqRangeHz{0.0, 1e6, true};
// A trial file's sample rate, Hz (an interferometer's stream; the daemon's output clock is bounded
// alike).
inline constexpr model::Range kSampleRateRangeHz{0.0, 1e8, true};
// Cycles of one trial and trials of one cell (the daemon's SWEEP takes these as its limits).
inline constexpr int kMaxCycles = 100000;
inline constexpr int kMaxTrialsPerCell = 100000;

// The reader reads each file whole into memory: at most this many bytes of each (a bigger file is
// refused naming it and the limit before anything is allocated for it).
inline constexpr std::size_t kMaxTrialFileBytes = std::size_t{256} << 20;  // trials/*.csv
inline constexpr std::size_t kMaxSweepFileBytes = std::size_t{256} << 20;  // sweep.csv
inline constexpr std::size_t kMaxYamlFileBytes = std::size_t{4} << 20;     // stage.yaml, plan.yaml

}  // namespace idm::recording
