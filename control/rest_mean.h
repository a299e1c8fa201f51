// The position shown at rest: the mean of the latest readings, so that the noise of a single
// word and the edge of a count do not make the position read at rest jump by a count now and then
// (the landing judges the same mean). Fixed storage: no allocation in the real-time loop.
#pragma once

#include <array>

namespace idm::control {

class RestMean {
 public:
  static constexpr int kMaxWords = 1000;

  // Starts over with a window of `words` readings (1 .. kMaxWords).
  void reset(int words);
  // Adds a reading; returns the mean of the latest min(words, readings since the reset).
  double add(double position_m);
  int count() const { return count_; }
  // Moves every reading held by dx_m (the readings' frame moved: a reference set the offset).
  void shift(double dx_m);

 private:
  std::array<double, kMaxWords> ring_m_{};
  int words_ = 1;
  int count_ = 0;
  int next_ = 0;
  double sum_m_ = 0;
};

}  // namespace idm::control
