// The files the report page inlines (generated from daemon/calibration/report/ and
// uPlot's npm package at configure time; report_assets.cpp.in).
#pragma once

#include <string_view>

namespace gyrotherm::calibration::report_assets {

std::string_view uplot_js();
std::string_view uplot_css();
std::string_view report_js();
std::string_view report_css();

}  // namespace gyrotherm::calibration::report_assets
