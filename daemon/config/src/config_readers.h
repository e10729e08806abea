// The section readers that config.cpp's build_config() calls from the other
// translation units of the config library: the devices under test
// (dut_config.cpp) and [lab] (lab_config.cpp). Private to daemon/config/src:
// not installed, not included from outside it.
#pragma once

#include <string>
#include <vector>

#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/config/config.h"
#include "gyrotherm/core/toml_errors.h"
#include "gyrotherm/core/toml_reader.h"

namespace gyrotherm::config::internal {

// dut_config.cpp: [gyro], the older form of one DUT.
void read_gyro(TableReader t, GyroSection& g);
// dut_config.cpp: every [[dut]] (`simulated`: [simulator] endpoints_file is
// set; `warnings`: what loads but is probably wrong).
void read_duts(TableReader& top, std::vector<DutSection>& duts, const StationSection& station,
               const ProbesSection& station_probes, bool simulated, TomlErrors& warnings);
// dut_config.cpp: [gyro] as one DUT, and back (StationConfig::gyro).
DutSection dut_from_gyro(const GyroSection& g, analysis::AxisOrientation orientation);
GyroSection gyro_of(const DutSection& d);

// lab_config.cpp: [lab], its paths taken relative to `source` (the config
// file's path).
void read_lab(TableReader t, LabSection& l, const std::string& source);

}  // namespace gyrotherm::config::internal
