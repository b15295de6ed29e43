// fbaconf's adapter for Xface 1.0's FAP file reader (copperdong/Xface, MPL-1.1; built outside the
// repository, see build.sh). It opens a .fap file with XFace::FAPFile::open as Xface does, with
// unit FAPU (every unit 1, so values are not rescaled), walks the frames with
// rewind()/getCurrentFAP()/getCurrentViseme()/getCurrentExpression()/next(), and writes
// Xface's state per frame as fbaconf's .fap text: the header with Xface's frame rate, then every
// FAP in every frame (Xface keeps 68 values per frame, 0 where the file set nothing) and FAP 1/2
// with the fields Xface keeps. Xface holds low-level values as float: each is written as the
// integer it holds (the .fap notes: values are integers), never in %g form (1.23457e+06, which no
// .fap reader takes); a non-integral value (read by atof from an invalid file) is written with
// its fraction, as Xface holds it.
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include "XFace/FapFile.h"

// The value Xface holds, as .fap text: its exact integer, or its decimal when it has a fraction.
static std::string fap_value(float v) {
    char buf[64];
    if (std::isfinite(v) && v == std::floor(v)) snprintf(buf, sizeof buf, "%.0f", (double)v);
    else snprintf(buf, sizeof buf, "%.9g", (double)v);
    return buf;
}

int main(int argc, char **argv) {
    if (argc != 3) {
        std::cerr << "usage: xface_fap_player IN.fap OUT.fap\n";
        return 2;
    }
    std::ifstream in(argv[1]);
    if (!in) {
        std::cerr << argv[1] << ": No such file or directory\n";
        return 2;
    }
    XFace::FAPU fapu;
    fapu.ES = fapu.IRISD = fapu.ENS = fapu.MNS = fapu.MW = fapu.AU = 1.0f;
    XFace::FAPFile faps;
    if (!faps.open(in, fapu) || faps.getFAPCount() == 0) {
        std::cerr << "xface: cannot read " << argv[1] << "\n";
        return 1;
    }
    std::ofstream out(argv[2]);
    out << "2.1 xface " << faps.getFPS() << " " << faps.getFAPCount() << "\n";
    faps.rewind();
    for (size_t row = 0; row < faps.getFAPCount(); ++row) {
        const std::vector<float> &f = faps.getCurrentFAP();
        if (f.size() < 68) break;
        const auto &v = faps.getCurrentViseme();
        const auto &e = faps.getCurrentExpression();
        bool vis = f[0] != 0, expr = f[1] != 0;
        out << (vis ? 1 : 0) << " " << (expr ? 1 : 0);
        for (int i = 2; i < 68; ++i) out << " 1";
        out << "\n" << row;
        if (vis) out << " " << v.viseme_select1 << " " << v.viseme_select2 << " " << v.viseme_blend << " " << v.viseme_def;
        if (expr) out << " " << e.expression_select1 << " " << e.expression_intensity1 << " " << e.expression_select2
                      << " " << e.expression_intensity2 << " " << e.init_face << " " << e.expression_def;
        for (int i = 2; i < 68; ++i) out << " " << fap_value(f[i]);
        out << "\n";
        faps.next();
    }
    return 0;
}
