#include "control/rest_mean.h"

#include <algorithm>

namespace idm::control {

void RestMean::reset(int words) {
  words_ = std::clamp(words, 1, kMaxWords);
  count_ = 0;
  next_ = 0;
  sum_m_ = 0;
}

double RestMean::add(double position_m) {
  const auto at = static_cast<std::size_t>(next_);
  if (count_ == words_)
    sum_m_ -= ring_m_[at];
  else
    ++count_;
  ring_m_[at] = position_m;
  sum_m_ += position_m;
  next_ = (next_ + 1) % words_;
  if (next_ == 0) {  // once a round, the sum afresh: no drift from the running updates
    sum_m_ = 0;
    for (int i = 0; i < count_; ++i) sum_m_ += ring_m_[static_cast<std::size_t>(i)];
  }
  return sum_m_ / count_;
}

void RestMean::shift(double dx_m) {
  for (int i = 0; i < count_; ++i) ring_m_[static_cast<std::size_t>(i)] += dx_m;
  sum_m_ += count_ * dx_m;
}

}  // namespace idm::control
