// fbaconf's adapter for Greta as a .fap PLAYER (isir/greta, LGPL-3.0; built outside the repository,
// see build.sh). It does what Greta's MPEG4Animatable does with FAP frames: the frames read by
// greta.core.animation.mpeg4.fap.FAPParser go into an APFrameList (performFAPFrames -> addFrames),
// and the face shows, at each frame time, APFrameList.getFrameAtTime(t): the first frame with every
// frame up to t blended in (a FAP keeps the value of the last frame that set it). The adapter
// writes that state at each parsed frame's number, in file order, as fbaconf's .fap text: a 2.1
// header with the rate Greta plays at (Constants.FRAME_PER_SECOND; Greta ignores the header line),
// then per frame the FAPs Greta's player holds. FAP 1 and 2 (viseme, expression): Greta keeps one
// integer each, not the high-level fields, so the adapter reports them as not set (mask 0).
// Exit 1 when Greta reads no frame (the parser catches its own exceptions and returns what it read).
import greta.core.animation.mpeg4.fap.FAPFrame;
import greta.core.animation.mpeg4.fap.FAPParser;
import greta.core.util.Constants;
import greta.core.util.animationparameters.APFrameList;
import java.io.File;
import java.io.PrintWriter;
import java.util.List;

public class GretaFapPlayer {
    public static void main(String[] args) throws Exception {
        if (args.length != 2) {
            System.err.println("usage: GretaFapPlayer IN.fap OUT.fap");
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
        int[] numbers = new int[frames.size()];
        for (int k = 0; k < numbers.length; k++) {
            numbers[k] = frames.get(k).getFrameNumber();  // before the list blends frames into its first one
        }
        FAPFrame first = new FAPFrame();
        first.setFrameNumber(0);
        APFrameList<FAPFrame> player = new APFrameList<>(first);  // as MPEG4Animatable builds it
        player.addFrames(frames);
        try (PrintWriter out = new PrintWriter(args[1], "UTF-8")) {
            out.println("2.1 greta " + Constants.FRAME_PER_SECOND + " " + numbers.length);
            for (int n : numbers) {
                FAPFrame f = player.getFrameAtTime(n);
                StringBuilder mask = new StringBuilder("0 0");
                StringBuilder vals = new StringBuilder(Integer.toString(n));
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
