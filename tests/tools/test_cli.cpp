// tools/cli.h's lengths with units (idmctl's arguments and --unit): every number written with
// every unit reads back as that many metres, rounded once; what is not a length is refused with
// a message naming the argument and the accepted units.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <string>

#include "model/stage.h"
#include "tools/cli.h"

using idm::model::InputError;
using idm::tools::exact_number;
using idm::tools::find_length_unit;
using idm::tools::format_length;
using idm::tools::LengthUnit;
using idm::tools::parse_length;
using idm::tools::parse_speed;

namespace {

const LengthUnit& unit(const char* name) {
  const LengthUnit* u = find_length_unit(name);
  if (!u) throw std::logic_error(name);
  return *u;
}

std::string refusal(const std::string& text, const LengthUnit* bare) {
  try {
    parse_length(text, "move X", bare);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

std::string speed_refusal(const std::string& text, const LengthUnit* bare) {
  try {
    parse_speed(text, "velocity SPEED", bare);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(Lengths, EveryNumberWithEveryUnitReadsBackAsItsMetres) {
  const std::pair<const char*, double> kUnits[] = {{"nm", 1e9}, {"um", 1e6}, {"mm", 1e3}, {"m", 1}};
  std::mt19937 random(11);
  std::uniform_real_distribution<double> mantissa(-10, 10);
  std::uniform_int_distribution<int> exponent(-12, 6);
  for (int k = 0; k < 2000; ++k) {
    const double number = mantissa(random) * std::pow(10.0, exponent(random));
    char text[64];
    std::snprintf(text, sizeof text, k % 2 ? "%.17g" : "%.6e", number);
    const double written = std::stod(text);
    for (const auto& [name, per_metre] : kUnits) {
      const double metres = parse_length(std::string(text) + name, "X", nullptr);
      EXPECT_EQ(metres, written / per_metre) << text << name;
      // exact_number reads back as the same double; format_length gives the number back in
      // its unit to 12 digits.
      EXPECT_EQ(std::stod(exact_number(metres)), metres) << text << name;
      EXPECT_NEAR(std::stod(format_length(metres, unit(name))), written, std::fabs(written) * 1e-11)
          << text << name;
    }
    // A bare number is in the unit given for it.
    EXPECT_EQ(parse_length(text, "X", &unit("m")), written);
    EXPECT_EQ(parse_length(text, "X", &unit("um")), written / 1e6);
  }
}

TEST(Lengths, FormattedToTwelveDigitsWithoutTheRoundingOfTheUnit) {
  EXPECT_EQ(format_length(1e-6, unit("nm")), "1000");
  EXPECT_EQ(format_length(-2.5e-7, unit("um")), "-0.25");
  EXPECT_EQ(format_length(9.93993679687e-07, unit("nm")), "993.993679687");
  EXPECT_EQ(format_length(0.0015, unit("mm")), "1.5");
  EXPECT_EQ(exact_number(2.5e-7), "2.5e-07");
}

TEST(Lengths, WhatIsNotALengthIsRefusedNamingTheArgumentAndTheUnits) {
  for (const char* bad : {"5km", "5MM", "5Mm", "5Um", "5nM", "1e", "um", "", "-", "5 um", "0x10m",
                          "1..2mm", "infm", "nanum", "1e400m", "5m5", "5mm,"}) {
    const std::string why = refusal(bad, &unit("m"));
    EXPECT_EQ(why.rfind(std::string("move X: '") + bad + "'", 0), 0u) << bad << ": " << why;
    EXPECT_NE(why.find("nm, um, mm, m"), std::string::npos) << bad << ": " << why;
  }
  EXPECT_EQ(refusal("5km", &unit("m")),
            "move X: '5km': unknown unit 'km', accepted nm, um, mm, m (case matters; a bare "
            "number is metres)");
  EXPECT_EQ(refusal("5\xC2\xB5m", &unit("m")),
            "move X: '5\xC2\xB5m': write um for micrometres; a number and a unit, one of nm, "
            "um, mm, m (e.g. 250nm, 1.5mm)");
  // Without a unit for bare numbers (idmctl --unit nm, um or mm), a bare number is ambiguous.
  EXPECT_EQ(refusal("5", nullptr),
            "move X: '5' has no unit: write 5um, 5m, ... (a bare number is metres only without "
            "--unit or with --unit m)");
  EXPECT_EQ(refusal("5um", nullptr), "");
}

TEST(Speeds, EveryNumberWithEveryUnitPerSecondReadsBackAsItsMetresPerSecond) {
  const std::pair<const char*, double> kUnits[] = {{"nm", 1e9}, {"um", 1e6}, {"mm", 1e3}, {"m", 1}};
  std::mt19937 random(13);
  std::uniform_real_distribution<double> mantissa(0, 10);
  std::uniform_int_distribution<int> exponent(-9, 3);
  for (int k = 0; k < 2000; ++k) {
    char text[64];
    std::snprintf(text, sizeof text, k % 2 ? "%.17g" : "%.6e",
                  mantissa(random) * std::pow(10.0, exponent(random)));
    const double written = std::stod(text);
    for (const auto& [name, per_metre] : kUnits)
      EXPECT_EQ(parse_speed(std::string(text) + name + "/s", "V", nullptr), written / per_metre)
          << text << name;
    EXPECT_EQ(parse_speed(text, "V", &unit("m")), written);
    EXPECT_EQ(parse_speed(text, "V", &unit("mm")), written / 1e3);
  }
}

TEST(Speeds, WhatIsNotASpeedIsRefusedNamingTheArgumentAndTheUnits) {
  for (const char* bad : {"5km/s", "5Um/s", "um/s", "/s", "5/s", "", "-", "5 um/s", "infm/s",
                          "5um/h", "5um/S", "5um//s", "5um/s/s", "1e400m/s", "5um", "5m"}) {
    const std::string why = speed_refusal(bad, &unit("m"));
    EXPECT_EQ(why.rfind(std::string("velocity SPEED: '") + bad + "'", 0), 0u) << bad << ": " << why;
    EXPECT_NE(why.find("nm/s, um/s, mm/s, m/s"), std::string::npos) << bad << ": " << why;
  }
  EXPECT_EQ(speed_refusal("5km/s", &unit("m")),
            "velocity SPEED: '5km/s': unknown unit 'km/s', accepted nm/s, um/s, mm/s, m/s (case "
            "matters; a bare number is m/s)");
  EXPECT_EQ(speed_refusal("400um", &unit("m")),
            "velocity SPEED: '400um' is a length, not a speed: write 400um/s (a number and a "
            "unit, one of nm/s, um/s, mm/s, m/s (e.g. 400um/s, 0.5mm/s))");
  EXPECT_EQ(speed_refusal("5\xC2\xB5m/s", &unit("m"))
                .rfind("velocity SPEED: '5\xC2\xB5m/s': write um/s for micrometres per second", 0),
            0u);
  EXPECT_EQ(speed_refusal("5", nullptr),
            "velocity SPEED: '5' has no unit: write 5um/s, 5m/s, ... (a bare number is m/s only "
            "without --unit or with --unit m)");
  EXPECT_EQ(speed_refusal("5um/s", nullptr), "");
  EXPECT_EQ(speed_refusal("-5um/s", nullptr), "");  // idmd judges the range (and names it)
}
