// fbaconf's PARSER-ONLY adapter for Greta's FAP parser (isir/greta, LGPL-3.0; built outside the
// repository, see build.sh). It reads a .fap file with greta.core.animation.mpeg4.fap.FAPParser
// exactly as Greta does and writes each parsed frame as it is: the FAPs of that frame's mask only.
// That is the parser's per-frame view, NOT Greta as a player (a FAP not in a frame's mask has no
// value here, while Greta's player holds it): GretaFapPlayer.java is the player adapter. Kept to
// show what the parser alone does (docs/third-party.md). Header: the rate Greta plays at (Greta
// ignores the file's header line). FAP 1 and 2 (viseme, expression): Greta keeps one integer
// each, not the high-level fields, so the adapter reports them as not set (mask 0).
import greta.core.animation.mpeg4.fap.FAPFrame;
import greta.core.animation.mpeg4.fap.FAPParser;
import greta.core.util.Constants;
import java.io.File;
import java.io.PrintWriter;
import java.util.List;

public class GretaFapParser {
    public static void main(String[] args) throws Exception {
        if (args.length != 2) {
            System.err.println("usage: GretaFapParser IN.fap OUT.fap");
            System.exit(2);
        }
        if (!new File(args[0]).isFile()) {
            System.err.println(args[0] + ": No such file or directory");
            System.exit(2);
        }
        List<FAPFrame> frames = new FAPParser().readFromFile(args[0], false);
        if (frames.isEmpty()) {
            System.err.println("greta: no frame read from " + args[0]);
            System.exit(1);
        }
        try (PrintWriter out = new PrintWriter(args[1], "UTF-8")) {
            out.println("2.1 greta " + Constants.FRAME_PER_SECOND + " " + frames.size());
            for (FAPFrame f : frames) {
                StringBuilder mask = new StringBuilder("0 0");
                StringBuilder vals = new StringBuilder(Integer.toString(f.getFrameNumber()));
                for (int i = 3; i <= 68; i++) {
                    boolean m = f.getMask(i);
                    mask.append(m ? " 1" : " 0");
                    if (m) vals.append(' ').append(f.getValue(i));
                }
                out.println(mask);
                out.println(vals);
            }
        }
    }
}
