// colonlight_host: runs an exported colonlight step (`colonlight export -o model.onnx`) over a clip's frames, as a
// C++ SLAM front end would, with nothing but ONNX Runtime, OpenCV's imgproc and the graph's JSON sidecar.
//
//   ffmpeg -i clip.mp4 -f rawvideo -pix_fmt rgb24 - | ./colonlight_host model.onnx 1350 1080 --out enhanced.rgb
//
// Reads raw RGB24 frames of WIDTH x HEIGHT from standard input, carries the recurrent state from frame to frame
// (h, c in -> h_out, c_out out; zeros at the start), turns the step's output into the frame's correction by the
// rule the sidecar gives for its head (gamma, gain-gamma or curve), pulls its tones toward the last output
// frame's where the sidecar's tone_match says so, starts afresh at a cut to another scene where its scene_cut
// does (and holds a featureless frame: the last table, no state change), applies the correction to the full-resolution frame through a 256-entry table, and prints one JSON line
// per frame on standard output. `--out FILE` writes the enhanced frames (raw RGB24) there. `--content MASK.pgm`
// shows the step only the scope's content area (`colonlight content CLIP -o MASK.pgm`) and writes the border and
// the fixed text unchanged. Errors: one line on standard error, exit 1 (2 for a usage error).
#include <onnxruntime_cxx_api.h>

#include <sys/stat.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>
#include <vector>

using json = nlohmann::json;
using Lut = std::array<std::uint8_t, 256>;

namespace {

struct Failure : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// What one frame's head output became: the table to apply (none: the frame unchanged) and what to report.
struct Correction {
    bool apply = false;
    Lut lut{};
    double gamma = 1.0;
    double gain = 1.0;
    std::vector<double> curve;  // the curve head's values at the knots
    bool clamped = false;
};

// np.interp's rule: linear between the two knots around x, the end values outside.
double interp(double x, const std::vector<double>& xs, const std::vector<double>& ys) {
    if (x <= xs.front()) return ys.front();
    if (x >= xs.back()) return ys.back();
    std::size_t j = std::upper_bound(xs.begin(), xs.end(), x) - xs.begin() - 1;
    double slope = (ys[j + 1] - ys[j]) / (xs[j + 1] - xs[j]);
    return slope * (x - xs[j]) + ys[j];
}

// The sidecar's correction rule for one head (its "correction" entry: the numbers of its "gamma" formula).
struct Rule {
    std::string head;
    double gamma_min = 0, gamma_max = 0;
    double log_gamma_span = 0, log_gain_span = 0, gain_min = 0, gain_max = 0;  // gain-gamma
    std::vector<double> knots;                                                // curve
    double slope_offset = 0, slope_max = 0, summary_at = 0;

    static Rule from_sidecar(const json& side) {
        const json& c = side.at("correction");
        if (c.is_null()) throw Failure("the sidecar does not say how this network's outputs become a correction");
        Rule r;
        r.head = c.at("head").get<std::string>();
        r.gamma_min = c.at("gamma_range").at(0).get<double>();
        r.gamma_max = c.at("gamma_range").at(1).get<double>();
        if (r.head == "gain-gamma") {
            r.log_gamma_span = c.at("log_gamma_span").get<double>();
            r.log_gain_span = c.at("log_gain_span").get<double>();
            r.gain_min = c.at("gain_range").at(0).get<double>();
            r.gain_max = c.at("gain_range").at(1).get<double>();
        } else if (r.head == "curve") {
            r.knots = c.at("knots").get<std::vector<double>>();
            r.slope_offset = c.at("slope_offset").get<double>();
            r.slope_max = c.at("slope_max").get<double>();
            r.summary_at = c.at("summary_at").get<double>();
        } else if (r.head != "gamma") {
            throw Failure("unknown head '" + r.head + "' in the sidecar");
        }
        return r;
    }

    Correction correct(const std::vector<float>& out) const {
        if (head == "gamma") return gamma_head(out.at(0));
        if (head == "gain-gamma") return gain_gamma_head(out.at(0), out.at(1));
        return curve_head(out);
    }

   private:
    // lut[v] = round(255 * min(1, gain * (v / 255) ^ gamma)), in double precision, rounded half to even.
    static Lut power_lut(double gain, double gamma) {
        Lut lut{};
        for (int v = 0; v < 256; ++v) {
            double y = std::pow(v / 255.0, gamma);
            if (gain != 1.0) y = std::min(1.0, gain * y);
            lut[v] = static_cast<std::uint8_t>(std::nearbyint(255.0 * y));
        }
        return lut;
    }

    Correction gamma_head(float a) const {  // gamma = 1 / a, clamped; a <= 0 or not finite: unchanged
        Correction c;
        if (!std::isfinite(a) || a <= 0.0f) {
            c.clamped = true;
        } else {
            double g = 1.0 / static_cast<double>(a);
            c.gamma = std::clamp(g, gamma_min, gamma_max);
            c.clamped = c.gamma != g;
        }
        c.apply = true;
        c.lut = power_lut(1.0, c.gamma);
        return c;
    }

    Correction gain_gamma_head(float z0, float z1) const {
        Correction c;
        c.apply = true;
        if (!std::isfinite(z0) || !std::isfinite(z1)) {
            c.clamped = true;
        } else {
            double gamma = std::exp(log_gamma_span * std::tanh(static_cast<double>(z0)));
            double gain = std::exp(log_gain_span * std::tanh(static_cast<double>(z1)));
            c.gamma = std::clamp(gamma, gamma_min, gamma_max);
            c.gain = std::clamp(gain, gain_min, gain_max);
            c.clamped = c.gamma != gamma || c.gain != gain;
        }
        c.lut = power_lut(c.gain, c.gamma);
        return c;
    }

    Correction curve_head(const std::vector<float>& z) const {
        Correction c;
        std::size_t segments = knots.size() - 1;
        if (z.size() != segments) throw Failure("the curve head gave " + std::to_string(z.size()) + " numbers");
        if (!std::all_of(z.begin(), z.end(), [](float v) { return std::isfinite(v); })) {
            c.clamped = true;  // no usable curve: the frame unchanged
            return c;
        }
        c.curve.assign(1, 0.0);
        for (std::size_t k = 0; k < segments; ++k) {
            double t = static_cast<double>(z[k]) + slope_offset;  // softplus(t) = log(1 + e^t), without overflow
            double slope = t == 0.0 ? std::log(2.0) : t < 0.0 ? std::log1p(std::exp(t)) : t + std::log1p(std::exp(-t));
            if (slope > slope_max) {
                slope = slope_max;
                c.clamped = true;
            }
            c.curve.push_back(c.curve.back() + slope * (knots[k + 1] - knots[k]));
        }
        double at = interp(summary_at, knots, c.curve);  // the summary gamma, for the record: a power law at m
        c.gamma = std::clamp(std::log(std::clamp(at, 1e-9, 1.0)) / std::log(summary_at), gamma_min, gamma_max);
        for (int v = 0; v < 256; ++v)
            c.lut[v] = static_cast<std::uint8_t>(
                std::nearbyint(255.0 * std::clamp(interp(v / 255.0, knots, c.curve), 0.0, 1.0)));
        c.apply = true;
        return c;
    }
};

// The tone match's subsample (tone_match.subsample): every step-th pixel each way, nearest neighbour, with the
// least step that leaves at most sample_pixels; the frame itself when it is that small.
cv::Mat subsample(const cv::Mat& rgb, double sample_pixels) {
    int step = std::max(
        1, static_cast<int>(std::ceil(std::sqrt(static_cast<double>(rgb.rows) * rgb.cols / sample_pixels))));
    if (step == 1) return rgb;
    cv::Mat sample;
    cv::resize(rgb, sample, cv::Size((rgb.cols + step - 1) / step, (rgb.rows + step - 1) / step), 0, 0,
               cv::INTER_NEAREST);
    return sample;
}

// colonlight.tone_match (the sidecar's "tone_match"): each output frame's tones pulled toward the last output
// frame's, over a subsample of the pixels not specular in either input frame. Off when its weight is 0 (the
// paper's one-gamma head) or the sidecar predates it.
class ToneMatcher {
   public:
    explicit ToneMatcher(const json& side) {
        if (!side.contains("tone_match")) return;
        const json& t = side.at("tone_match");
        weight_ = t.at("weight").get<double>();
        sample_pixels_ = t.at("sample_pixels").get<double>();
        specular_ = t.at("specular_level").get<int>();
        min_shared_ = t.at("min_shared").get<int>();
    }

    bool on() const { return weight_ > 0.0; }

    // The table to apply to rgb: the head's table, then weight of the match of its result to the last output.
    Lut table(const cv::Mat& rgb, const Lut& head) {
        cv::Mat sample = subsample(rgb, sample_pixels_), ok = usable(sample);
        Lut out = head;
        if (has_previous_ && previous_.size() == sample.size()) {
            cv::Mat shared;
            cv::bitwise_and(ok, previous_ok_, shared);
            if (cv::countNonZero(shared) >= min_shared_) {
                std::vector<double> match = matching(histogram(sample, shared, head),
                                                     histogram(previous_, shared, previous_table_));
                Lut pulled{};
                double running = 0.0;
                for (int v = 0; v < 256; ++v) {
                    double p = (1.0 - weight_) * v + weight_ * match[v];
                    running = v == 0 ? p : std::max(running, p);
                    pulled[v] = static_cast<std::uint8_t>(std::clamp(std::nearbyint(running), 0.0, 255.0));
                }
                for (int v = 0; v < 256; ++v) out[v] = pulled[head[v]];
            }
        }
        remember(sample, ok, out);
        return out;
    }

    // A frame written through table without matching (a seed frame): the next frame matches to it.
    void keep(const cv::Mat& rgb, const Lut& table) {
        cv::Mat sample = subsample(rgb, sample_pixels_);
        remember(sample, usable(sample), table);
    }

   private:
    double weight_ = 0.0, sample_pixels_ = 1.0;
    int specular_ = 255, min_shared_ = 0;
    bool has_previous_ = false;
    cv::Mat previous_, previous_ok_;
    Lut previous_table_{};

    void remember(const cv::Mat& sample, const cv::Mat& ok, const Lut& table) {
        previous_ = sample.clone();  // the caller's frame buffer is reused
        previous_ok_ = ok;
        previous_table_ = table;
        has_previous_ = true;
    }

    cv::Mat usable(const cv::Mat& sample) const {
        cv::Mat gray;
        cv::cvtColor(sample, gray, cv::COLOR_RGB2GRAY);
        return gray <= specular_;
    }

    // The pooled R, G, B counts of table[sample] over mask.
    static std::vector<double> histogram(const cv::Mat& sample, const cv::Mat& mask, const Lut& table) {
        std::vector<double> counts(256, 0.0);
        const int bins = 256;
        const float range[] = {0.0f, 256.0f};
        const float* ranges[] = {range};
        for (int c = 0; c < 3; ++c) {
            cv::Mat h;
            cv::calcHist(&sample, 1, &c, mask, h, 1, &bins, ranges);
            for (int v = 0; v < 256; ++v) counts[table[v]] += h.at<float>(v);
        }
        return counts;
    }

    // The levels with counts and their mid-bin quantiles.
    static void quantiles(const std::vector<double>& counts, std::vector<double>& levels, std::vector<double>& q) {
        double total = 0.0, running = 0.0;
        for (double n : counts) total += n;
        for (int v = 0; v < 256; ++v) {
            running += counts[v];
            if (counts[v] > 0.0) {
                levels.push_back(v);
                q.push_back((running - counts[v] / 2) / total);
            }
        }
    }

    // The table that maps tones counted as source onto tones counted as reference (tone_match.matching_table).
    static std::vector<double> matching(const std::vector<double>& source, const std::vector<double>& reference) {
        std::vector<double> ls, qs, lr, qr;
        quantiles(source, ls, qs);
        quantiles(reference, lr, qr);
        std::vector<double> mapped;
        for (double q : qs) mapped.push_back(interp(q, qr, lr));
        std::vector<double> table(256);
        for (int v = 0; v < 256; ++v) {
            double t = v < ls.front()  ? mapped.front() - (ls.front() - v)
                       : v > ls.back() ? mapped.back() + (v - ls.back())
                                       : interp(v, ls, mapped);
            table[v] = std::clamp(t, 0.0, 255.0);
        }
        return table;
    }
};

// colonlight.scene_cut (the sidecar's "scene_cut"): a frame whose grey thumbnail does not keep the last frame's
// order of pixel brightness (rank correlation below the threshold; lighting changes keep it) starts a new clip;
// a frame whose thumbnail is one level (a dropout, a flash) has no order to judge and is held.
// Off when the threshold is 0 (the paper's one-gamma head) or the sidecar predates it.
enum class Verdict { continues, cut, featureless };

class SceneCuts {
   public:
    explicit SceneCuts(const json& side) {
        if (!side.contains("scene_cut")) return;
        const json& t = side.at("scene_cut");
        threshold_ = t.at("threshold").get<double>();
        side_ = t.at("thumb_side").get<int>();
        sample_pixels_ = side.at("tone_match").at("sample_pixels").get<double>();
    }

    bool on() const { return threshold_ > 0.0; }

    // Whether rgb continues the last frame judged, starts a new scene (never the first), or is featureless
    // (neither, and not remembered); remembers the others.
    Verdict judge(const cv::Mat& rgb) {
        std::vector<double> ranks = centred_ranks(thumbnail(rgb));
        if (std::all_of(ranks.begin(), ranks.end(), [](double r) { return r == 0.0; })) return Verdict::featureless;
        const bool cut = has_previous_ && correlation(previous_, ranks) < threshold_;
        previous_ = std::move(ranks);
        has_previous_ = true;
        return cut ? Verdict::cut : Verdict::continues;
    }

   private:
    double threshold_ = 0.0, sample_pixels_ = 1.0;
    int side_ = 1;
    bool has_previous_ = false;
    std::vector<double> previous_;

    // The tone match's subsample, area-averaged to side x side, in grey.
    cv::Mat thumbnail(const cv::Mat& rgb) const {
        cv::Mat small, grey;
        cv::resize(subsample(rgb, sample_pixels_), small, cv::Size(side_, side_), 0, 0, cv::INTER_AREA);
        cv::cvtColor(small, grey, cv::COLOR_RGB2GRAY);
        return grey;
    }

    // Each pixel's rank (ties: their mean rank) less the mean rank: multiples of 1/2, so every sum is exact.
    static std::vector<double> centred_ranks(const cv::Mat& grey) {
        std::array<double, 256> counts{}, rank{};
        for (int y = 0; y < grey.rows; ++y)
            for (int x = 0; x < grey.cols; ++x) counts[grey.at<std::uint8_t>(y, x)] += 1.0;
        double darker = 0.0;
        for (int v = 0; v < 256; ++v) {
            rank[v] = darker + (counts[v] + 1.0) / 2.0;
            darker += counts[v];
        }
        const double centre = (static_cast<double>(grey.total()) + 1.0) / 2.0;
        std::vector<double> out;
        out.reserve(grey.total());
        for (int y = 0; y < grey.rows; ++y)
            for (int x = 0; x < grey.cols; ++x) out.push_back(rank[grey.at<std::uint8_t>(y, x)] - centre);
        return out;
    }

    // Spearman's correlation from centred ranks; 0 when either frame is flat.
    static double correlation(const std::vector<double>& r, const std::vector<double>& s) {
        double rs = 0.0, rr = 0.0, ss = 0.0;
        for (std::size_t i = 0; i < r.size(); ++i) {
            rs += r[i] * s[i];
            rr += r[i] * r[i];
            ss += s[i] * s[i];
        }
        const double denominator = rr * ss;
        return denominator > 0.0 ? rs / std::sqrt(denominator) : 0.0;
    }
};

// The copy of the frame the network sees (the sidecar's "resize"): a frame whose shorter side is over
// presample * size is first resampled bilinearly to that square, then area-averaged to size x size; a frame of
// that size already is used as is.
cv::Mat network_input(const cv::Mat& rgb, int size, int presample) {
    if (rgb.rows == size && rgb.cols == size) return rgb;
    cv::Mat small = rgb;
    if (std::min(small.rows, small.cols) > presample * size)
        cv::resize(small, small, cv::Size(presample * size, presample * size), 0, 0, cv::INTER_LINEAR);
    cv::resize(small, small, cv::Size(size, size), 0, 0, cv::INTER_AREA);
    return small;
}

std::string number(double v) {
    if (!std::isfinite(v)) return "null";
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    return buf;
}

// A scope's content area, read from colonlight's mask image (`colonlight content CLIP -o MASK.pgm`: binary PGM,
// 255 where the scene shows, 0 outside the field of view, anything between fixed text inside it). The step sees
// the field of view's bounding box with every non-scene pixel in it filled with the scene's mean colour (rounded
// half to even, as colonlight rounds), and only scene pixels are written corrected: colonlight.content's rule,
// so a host given the mask writes what `colonlight enhance --content auto` writes for that area. Off (the whole
// frame, as without a mask) when every pixel is scene.
class ContentArea {
   public:
    ContentArea() = default;

    static ContentArea read(const std::string& path, int width, int height) {
        // a regular file only: opening a FIFO without a writer blocks forever, a folder opens and reads nothing
        struct stat info {};
        if (stat(path.c_str(), &info) != 0)
            throw Failure(path + ": cannot read the content mask (" + std::strerror(errno) + ")");
        if (!S_ISREG(info.st_mode)) throw Failure(path + ": not a regular file (a folder, FIFO, socket or device)");
        std::ifstream in(path, std::ios::binary);
        if (!in) throw Failure(path + ": cannot read the content mask (" + std::strerror(errno) + ")");
        char magic[2] = {};
        if (!in.read(magic, 2) || magic[0] != 'P' || magic[1] != '5' || !std::isspace(in.peek()))
            throw Failure(path + ": not an 8-bit binary PGM (P5, maxval 255) mask: write it with colonlight content");
        const int mask_width = header_number(in, path), mask_height = header_number(in, path);
        const int maxval = header_number(in, path);
        if (maxval != 255)
            throw Failure(path + ": not an 8-bit binary PGM (P5, maxval 255) mask: write it with colonlight content");
        if (mask_width != width || mask_height != height)
            throw Failure(path + ": the mask is " + std::to_string(mask_width) + "x" + std::to_string(mask_height) +
                          ", the frames are " + std::to_string(width) + "x" + std::to_string(height));
        // the single whitespace byte before the raster: anything else (a comment there) would shift every pixel
        if (!std::isspace(in.get())) throw Failure(path + ": not an 8-bit binary PGM (P5) mask: its header is damaged");
        // the raster's length from the file's size, before it is allocated; bytes past it are a shifted raster
        // (CR LF line ends, a comment after maxval) or another file's data, as colonlight.content_mask refuses them
        const long long raster = static_cast<long long>(width) * height, left = info.st_size - in.tellg();
        if (left < raster) throw Failure(path + ": the mask is cut short");
        if (left > raster)
            throw Failure(path + ": " + std::to_string(left - raster) + " bytes past the mask's " +
                          std::to_string(width) + "x" + std::to_string(height) + " raster (a damaged header?)");
        cv::Mat levels(height, width, CV_8U);
        in.read(reinterpret_cast<char*>(levels.data), static_cast<std::streamsize>(levels.total()));
        if (static_cast<std::size_t>(in.gcount()) != levels.total()) throw Failure(path + ": the mask is cut short");
        ContentArea area;
        area.scene_ = levels == 255;
        if (cv::countNonZero(area.scene_) == 0) throw Failure(path + ": no scene pixel (255) in the mask");
        const cv::Mat fov = levels != 0;
        area.on_ = cv::countNonZero(area.scene_) != static_cast<int>(levels.total());
        area.box_ = cv::boundingRect(fov);
        area.inside_ = area.scene_(area.box_).clone();
        area.holes_ = area.inside_ == 0;
        area.has_holes_ = cv::countNonZero(area.holes_) > 0;
        return area;
    }

    bool on() const { return on_; }

    // What the step is shown of rgb: the box, its non-scene pixels filled with the scene's mean colour.
    cv::Mat method_input(const cv::Mat& rgb) const {
        cv::Mat box = rgb(box_).clone();
        if (has_holes_) {
            cv::Scalar mean = cv::mean(box, inside_);
            for (int ch = 0; ch < 3; ++ch) mean[ch] = std::nearbyint(mean[ch]);
            box.setTo(cv::Scalar(mean[0], mean[1], mean[2]), holes_);
        }
        return box;
    }

    // rgb with table applied to its scene pixels only (border and text as they came in).
    cv::Mat corrected(const cv::Mat& rgb, const cv::Mat& table) const {
        cv::Mat out = rgb.clone(), box;
        cv::LUT(rgb(box_), table, box);
        cv::Mat target = out(box_);
        box.copyTo(target, inside_);
        return out;
    }

   private:
    bool on_ = false, has_holes_ = false;
    cv::Rect box_;
    cv::Mat scene_, inside_, holes_;

    // The next number of a PGM header, past whitespace and # comments.
    static int header_number(std::istream& in, const std::string& path) {
        while (true) {
            in >> std::ws;
            if (in.peek() != '#') break;
            std::string comment;
            std::getline(in, comment);
        }
        long value = -1;
        if (!(in >> value) || value <= 0 || value > 1000000)
            throw Failure(path + ": not an 8-bit binary PGM (P5) mask: its header is damaged");
        return static_cast<int>(value);
    }
};

// Writes rgb through c's table (every sample, every channel; scene pixels only under a content area), or as it is
// when c applies none.
void write_frame(std::ofstream& out, const std::string& out_path, const cv::Mat& rgb, Correction& c,
                 const ContentArea& content) {
    cv::Mat enhanced = rgb;
    if (c.apply) {
        const cv::Mat table(1, 256, CV_8U, c.lut.data());
        if (content.on())
            enhanced = content.corrected(rgb, table);
        else
            cv::LUT(rgb, table, enhanced);
    }
    out.write(reinterpret_cast<const char*>(enhanced.data), static_cast<std::streamsize>(enhanced.total() * 3));
    if (!out) throw Failure(out_path + ": write failed");
}

json read_json(const std::string& path) {
    std::ifstream in(path);
    if (!in) throw Failure(path + ": cannot read the sidecar (export writes it beside the graph)");
    try {
        return json::parse(in);
    } catch (const json::exception& e) {
        throw Failure(path + ": not a JSON sidecar (" + e.what() + ")");
    }
}

int run(const std::string& model, int width, int height, const std::string& out_path, const std::string& mask) {
    const json side = read_json(model + ".json");
    const int size = side.at("input_size").get<int>();
    const json& frame_input = side.at("inputs").at(0);
    if (!frame_input.contains("presample"))  // sidecars before colonlight's session 15 described a pyramid resize
        throw Failure(model + ".json: no \"presample\" in its frame input (an older export); re-export the model");
    const int presample = frame_input.at("presample").get<int>();
    const long seeds = side.at("seed_frames").at("count").get<long>();
    const Rule rule = Rule::from_sidecar(side);
    ToneMatcher matcher(side);
    SceneCuts cuts(side);
    const ContentArea content = mask.empty() ? ContentArea() : ContentArea::read(mask, width, height);

    // Inputs: the frame, then the state tensors (zeros); outputs: the head's, then each state's "<name>_out".
    std::vector<std::string> in_names, out_names;
    std::vector<std::vector<int64_t>> in_shapes;
    std::vector<std::vector<float>> in_data;
    for (const json& i : side.at("inputs")) {
        in_names.push_back(i.at("name").get<std::string>());
        in_shapes.push_back(i.at("shape").get<std::vector<int64_t>>());
        int64_t n = 1;
        for (int64_t d : in_shapes.back()) n *= d;
        in_data.emplace_back(static_cast<std::size_t>(n), 0.0f);
    }
    if (in_names.empty() || in_names[0] != "frame") throw Failure("the sidecar's first input is not 'frame'");
    for (const json& o : side.at("outputs")) out_names.push_back(o.at("name").get<std::string>());
    const std::size_t n_state = in_names.size() - 1, n_head = out_names.size() - n_state;

    Ort::Env env(ORT_LOGGING_LEVEL_WARNING, "colonlight");
    Ort::SessionOptions options;
    options.SetIntraOpNumThreads(1);  // the step is small: leave the cores to SLAM
    options.SetInterOpNumThreads(1);
    options.AddConfigEntry("session.intra_op.allow_spinning", "0");
    Ort::Session session(env, model.c_str(), options);
    auto memory = Ort::MemoryInfo::CreateCpu(OrtArenaAllocator, OrtMemTypeDefault);
    std::vector<const char*> in_c, out_c;
    for (auto& n : in_names) in_c.push_back(n.c_str());
    for (auto& n : out_names) out_c.push_back(n.c_str());

    std::ofstream out_file;
    if (!out_path.empty()) {
        out_file.open(out_path, std::ios::binary);
        if (!out_file) throw Failure(out_path + ": cannot write");
    }
    const std::size_t frame_bytes = static_cast<std::size_t>(width) * height * 3;
    std::vector<std::uint8_t> buffer(frame_bytes);
    long since_start = 0;  // frames run since the clip's start or its last scene cut
    Correction last;       // the last frame's applied correction: a held frame is written through it
    for (long index = 0;; ++index) {
        std::cin.read(reinterpret_cast<char*>(buffer.data()), static_cast<std::streamsize>(frame_bytes));
        if (std::cin.gcount() == 0) break;
        if (static_cast<std::size_t>(std::cin.gcount()) != frame_bytes)
            throw Failure("standard input ended inside frame " + std::to_string(index) + " (not " +
                          std::to_string(width) + "x" + std::to_string(height) + " RGB24?)");
        const cv::Mat whole(height, width, CV_8UC3, buffer.data());
        const cv::Mat rgb = content.on() ? content.method_input(whole) : whole;  // what the step and its rules see
        const Verdict verdict = cuts.on() ? cuts.judge(rgb) : Verdict::continues;
        if (verdict == Verdict::featureless) {  // held: the last frame's table, no state changes
            std::cout << "{\"index\": " << index << ", \"head\": [], \"seed\": false, \"scene_cut\": false, "
                      << "\"held\": true, \"gamma\": " << number(last.gamma) << ", \"clamped\": false}\n"
                      << std::flush;
            if (out_file.is_open()) write_frame(out_file, out_path, whole, last, content);
            continue;
        }
        const bool cut = verdict == Verdict::cut;
        if (cut) {  // a new clip: the state, the frame count, the tone match's memory and the last table start again
            for (std::size_t s = 1; s < in_data.size(); ++s) std::fill(in_data[s].begin(), in_data[s].end(), 0.0f);
            since_start = 0;
            matcher = ToneMatcher(side);
            last = Correction{};
        }
        cv::Mat x = network_input(rgb, size, presample);
        std::vector<float>& frame = in_data[0];  // NCHW, channels R G B, value / 255
        for (int y = 0; y < size; ++y)
            for (int c0 = 0; c0 < size; ++c0)
                for (int ch = 0; ch < 3; ++ch)
                    frame[(static_cast<std::size_t>(ch) * size + y) * size + c0] = x.at<cv::Vec3b>(y, c0)[ch] / 255.f;

        std::vector<Ort::Value> inputs;
        for (std::size_t i = 0; i < in_names.size(); ++i)
            inputs.push_back(Ort::Value::CreateTensor<float>(memory, in_data[i].data(), in_data[i].size(),
                                                             in_shapes[i].data(), in_shapes[i].size()));
        auto outputs = session.Run(Ort::RunOptions{nullptr}, in_c.data(), inputs.data(), inputs.size(), out_c.data(),
                                   out_c.size());
        std::vector<float> head;
        for (std::size_t o = 0; o < n_head; ++o) {
            const float* p = outputs[o].GetTensorData<float>();
            head.insert(head.end(), p, p + outputs[o].GetTensorTypeAndShapeInfo().GetElementCount());
        }
        for (std::size_t s = 0; s < n_state; ++s) {  // the state for the next frame
            const float* p = outputs[n_head + s].GetTensorData<float>();
            std::copy_n(p, in_data[1 + s].size(), in_data[1 + s].begin());
        }

        const bool seed = since_start++ < seeds;  // seeds build the state and pass through unchanged
        Correction c = seed ? Correction{} : rule.correct(head);
        if (matcher.on()) {
            Lut identity{};
            for (int v = 0; v < 256; ++v) identity[v] = static_cast<std::uint8_t>(v);
            if (seed) {
                matcher.keep(rgb, identity);
            } else {
                c.lut = matcher.table(rgb, c.apply ? c.lut : identity);
                c.apply = true;
            }
        }
        std::string line = "{\"index\": " + std::to_string(index) + ", \"head\": [";
        for (std::size_t i = 0; i < head.size(); ++i) line += (i ? ", " : "") + number(head[i]);
        line += "], \"seed\": " + std::string(seed ? "true" : "false") + ", \"scene_cut\": " +
                std::string(cut ? "true" : "false") + ", \"held\": false, \"gamma\": " + number(c.gamma);
        if (rule.head == "gain-gamma") line += ", \"gain\": " + number(c.gain);
        if (rule.head == "curve" && !c.curve.empty()) {
            line += ", \"curve\": [";
            for (std::size_t i = 0; i < c.curve.size(); ++i) line += (i ? ", " : "") + number(c.curve[i]);
            line += "]";
        }
        line += ", \"clamped\": " + std::string(c.clamped ? "true" : "false") + "}";
        std::cout << line << '\n' << std::flush;

        if (out_file.is_open()) write_frame(out_file, out_path, whole, c, content);
        last = c;
    }
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    std::string out_path, mask;
    std::vector<std::string> args;
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        if (a == "--out" && i + 1 < argc)
            out_path = argv[++i];
        else if (a == "--content" && i + 1 < argc)
            mask = argv[++i];
        else
            args.push_back(a);
    }
    int width = 0, height = 0;
    if (args.size() == 3) {
        width = std::atoi(args[1].c_str());
        height = std::atoi(args[2].c_str());
    }
    if (width <= 0 || height <= 0) {
        std::cerr << "usage: colonlight_host MODEL.onnx WIDTH HEIGHT [--out ENHANCED.rgb] [--content MASK.pgm] "
                     "< frames.rgb (raw RGB24)\n";
        return 2;
    }
    try {
        return run(args[0], width, height, out_path, mask);
    } catch (const Failure& e) {
        std::cerr << "error: " << e.what() << '\n';
    } catch (const Ort::Exception& e) {
        std::cerr << "error: " << args[0] << ": " << e.what() << '\n';
    } catch (const json::exception& e) {
        std::cerr << "error: " << args[0] << ".json: " << e.what() << '\n';
    } catch (const std::exception& e) {
        std::cerr << "error: " << e.what() << '\n';
    }
    return 1;
}
