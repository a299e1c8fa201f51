// CLOCK_MONOTONIC in seconds and absolute-deadline sleeps (clock_nanosleep, TIMER_ABSTIME), for
// the backends that pace themselves to the wall clock and for wait loops.
#pragma once

namespace idm::drivers {

// Seconds on CLOCK_MONOTONIC.
double monotonic_s();
// Sleeps until monotonic_s() >= deadline_s (clock_nanosleep with TIMER_ABSTIME, restarted after
// signals); returns at once when the deadline has passed.
void sleep_until_s(double deadline_s);

}  // namespace idm::drivers
