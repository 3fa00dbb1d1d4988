package milling.twin.importers;

import java.io.BufferedWriter;
import java.io.File;
import java.io.IOException;
import java.math.BigDecimal;
import java.math.MathContext;
import java.math.RoundingMode;
import java.nio.charset.StandardCharsets;
import java.nio.file.Files;
import java.nio.file.Path;
import java.nio.file.Paths;
import java.util.ArrayList;
import java.util.LinkedHashMap;
import java.util.List;
import java.util.Locale;
import java.util.Map;

import no.ntnu.ihb.fmi4j.FmiStatus;
import no.ntnu.ihb.fmi4j.importer.fmi2.CoSimulationSlave;
import no.ntnu.ihb.fmi4j.importer.fmi2.Fmu;
import no.ntnu.ihb.fmi4j.modeldescription.variables.Causality;
import no.ntnu.ihb.fmi4j.modeldescription.variables.ModelVariables;
import no.ntnu.ihb.fmi4j.modeldescription.variables.TypedScalarVariable;
import no.ntnu.ihb.fmi4j.modeldescription.variables.VariableType;

/**
 * Runs one FMI 2 co-simulation FMU through FMI4j with a fixed communication step and writes every output
 * after every step as CSV.
 *
 * <p>Usage: {@code java -jar fmi4j-driver.jar MODEL.fmu PLAN.csv OUT.csv}
 *
 * <p>The plan is a CSV file without header, one directive per line ({@code #} starts a comment):
 * <pre>
 * step_size,0.001          communication step size (s)
 * steps,10                 number of doStep calls
 * start,name,value         a start value, set after instantiation, before initialization mode
 * input,k,name,value       an input set before the k-th doStep (k = 0 .. steps-1)
 * </pre>
 * Real values are parsed with {@link Double#parseDouble} (Python's repr round-trips exactly), Integer values
 * as integers, Boolean values as 0/1 or false/true.
 *
 * <p>The output has the header {@code time,<every output in model description order>} and one row per step,
 * the time being the communication point reached (accumulated as t += step_size, as fmpy does) and Real values
 * written with 17 significant digits (exact round trip).
 */
public final class Fmi4jDriver {

    private static final MathContext DIGITS = new MathContext(17, RoundingMode.HALF_EVEN);

    private Fmi4jDriver() {
    }

    /** One value to set: which variable, what value, where the plan says so. */
    private static final class Assignment {
        final TypedScalarVariable<?> variable;
        final String value;
        final String where;

        Assignment(TypedScalarVariable<?> variable, String value, String where) {
            this.variable = variable;
            this.value = value;
            this.where = where;
        }
    }

    /** The parsed plan. */
    private static final class Plan {
        double stepSize = Double.NaN;
        int steps = -1;
        final List<Assignment> starts = new ArrayList<>();
        final Map<Integer, List<Assignment>> inputs = new LinkedHashMap<>();
    }

    /** A failure the user can act on: the message names the file, line, call or variable. */
    static final class DriverException extends Exception {
        private static final long serialVersionUID = 1L;

        DriverException(String message) {
            super(message);
        }
    }

    public static void main(String[] args) {
        if (args.length != 3) {
            System.err.println("usage: java -jar fmi4j-driver.jar MODEL.fmu PLAN.csv OUT.csv");
            System.exit(2);
        }
        try {
            run(new File(args[0]), Paths.get(args[1]), Paths.get(args[2]));
        } catch (DriverException | IOException e) {
            System.err.println("fmi4j-driver: " + e.getMessage());
            System.exit(1);
        }
    }

    static void run(File fmuFile, Path planFile, Path outFile) throws DriverException, IOException {
        if (!fmuFile.isFile()) {
            throw new DriverException(fmuFile + ": no such FMU");
        }
        Fmu loaded;
        try {
            loaded = Fmu.from(fmuFile);
        } catch (UnsupportedOperationException e) {  // FMI4j 0.38 imports FMI 1.0 and 2.0 only
            throw new DriverException(fmuFile + ": FMI4j cannot import it: " + e.getMessage());
        }
        try (Fmu fmu = loaded) {
            ModelVariables variables = fmu.getModelDescription().getModelVariables();
            Plan plan = readPlan(planFile, variables);
            List<TypedScalarVariable<?>> outputs = variables.getByCausality(Causality.OUTPUT);
            try (CoSimulationSlave slave = fmu.asCoSimulationFmu().newInstance("dut");
                 BufferedWriter out = Files.newBufferedWriter(outFile, StandardCharsets.UTF_8)) {
                StringBuilder header = new StringBuilder("time");
                for (TypedScalarVariable<?> v : outputs) {
                    header.append(',').append(csvField(v.getName()));
                }
                out.write(header.append('\n').toString());
                simulate(slave, plan, outputs, out, fmuFile.getName());
                check(slave.terminate(), slave, fmuFile.getName() + ": fmi2Terminate");
            }
        }
    }

    private static void simulate(CoSimulationSlave slave, Plan plan, List<TypedScalarVariable<?>> outputs,
                                 BufferedWriter out, String fmuName) throws DriverException, IOException {
        check(slave.setupExperiment(0.0, 0.0, 0.0), slave, fmuName + ": fmi2SetupExperiment");
        for (Assignment a : plan.starts) {
            set(slave, a, fmuName);
        }
        check(slave.enterInitializationMode(), slave, fmuName + ": fmi2EnterInitializationMode");
        check(slave.exitInitializationMode(), slave, fmuName + ": fmi2ExitInitializationMode");
        double time = 0.0;
        for (int k = 0; k < plan.steps; k++) {
            for (Assignment a : plan.inputs.getOrDefault(k, List.of())) {
                set(slave, a, fmuName);
            }
            slave.doStep(time, plan.stepSize);
            FmiStatus status = slave.getLastStatus();
            if (status != FmiStatus.OK && status != FmiStatus.Warning) {
                throw new DriverException(fmuName + ": fmi2DoStep at t = " + time + " (step " + k + ") returned "
                        + status);
            }
            time += plan.stepSize;
            StringBuilder row = new StringBuilder(format(time));
            for (TypedScalarVariable<?> v : outputs) {
                row.append(',').append(get(slave, v, fmuName));
            }
            out.write(row.append('\n').toString());
        }
    }

    /** A CSV field, quoted when it holds a comma or a quote (FMI 2 array elements are named "name[i,j]"). */
    private static String csvField(String text) {
        if (text.indexOf(',') < 0 && text.indexOf('"') < 0 && text.indexOf('\n') < 0) {
            return text;
        }
        return '"' + text.replace("\"", "\"\"") + '"';
    }

    /** 17 significant digits of the exact binary value: parses back to the same double. */
    private static String format(double value) {
        if (Double.isNaN(value) || Double.isInfinite(value)) {
            return Double.toString(value);
        }
        return new BigDecimal(value).round(DIGITS).toString();
    }

    private static void check(boolean ok, CoSimulationSlave slave, String call) throws DriverException {
        FmiStatus status = slave.getLastStatus();
        if (!ok && status != FmiStatus.Warning) {
            throw new DriverException(call + " returned " + status);
        }
    }

    private static void set(CoSimulationSlave slave, Assignment a, String fmuName) throws DriverException {
        long[] vr = {a.variable.getValueReference()};
        String name = a.variable.getName();
        FmiStatus status;
        try {
            VariableType type = a.variable.getType();
            if (type == VariableType.REAL) {
                status = slave.writeReal(vr, new double[] {Double.parseDouble(a.value)});
            } else if (type == VariableType.INTEGER || type == VariableType.ENUMERATION) {
                status = slave.writeInteger(vr, new int[] {Integer.parseInt(a.value)});
            } else if (type == VariableType.BOOLEAN) {
                status = slave.writeBoolean(vr, fmi2Booleans(parseBoolean(a.value, a.where, name)));
            } else {
                status = slave.writeString(vr, new String[] {a.value});
            }
        } catch (NumberFormatException e) {
            throw new DriverException(a.where + ": variable " + name + ": bad value '" + a.value + "'");
        }
        if (status != FmiStatus.OK && status != FmiStatus.Warning) {
            throw new DriverException(a.where + ": " + fmuName + ": setting " + name + " = " + a.value
                    + " returned " + status);
        }
    }

    /**
     * FMI4j 0.38's native setBoolean hands the JVM's 1-byte jboolean array to fmi2SetBoolean as the 4-byte
     * fmi2Boolean array it expects (see docs/importers.md), so the FMU reads the value together with 3 bytes of
     * whatever follows it, and false arrives as true. The array below gives every value its own 4 bytes: the
     * value in the lowest-addressed byte and zeros after it, which is the int 0 or 1 on a little-endian
     * machine (x86_64, aarch64). FMI4j's getBoolean converts element by element and needs nothing.
     */
    static boolean[] fmi2Booleans(boolean value) {
        boolean[] bytes = new boolean[Integer.BYTES];
        bytes[java.nio.ByteOrder.nativeOrder() == java.nio.ByteOrder.LITTLE_ENDIAN ? 0 : Integer.BYTES - 1] = value;
        return bytes;
    }

    private static boolean parseBoolean(String text, String where, String name) throws DriverException {
        switch (text.trim().toLowerCase(Locale.ROOT)) {
            case "1": case "1.0": case "true":
                return true;
            case "0": case "0.0": case "false":
                return false;
            default:
                throw new DriverException(where + ": variable " + name + ": '" + text + "' is not a Boolean");
        }
    }

    private static String get(CoSimulationSlave slave, TypedScalarVariable<?> v, String fmuName)
            throws DriverException {
        long[] vr = {v.getValueReference()};
        FmiStatus status;
        String text;
        VariableType type = v.getType();
        if (type == VariableType.REAL) {
            double[] value = new double[1];
            status = slave.readReal(vr, value);
            text = format(value[0]);
        } else if (type == VariableType.INTEGER || type == VariableType.ENUMERATION) {
            int[] value = new int[1];
            status = slave.readInteger(vr, value);
            text = Integer.toString(value[0]);
        } else if (type == VariableType.BOOLEAN) {
            boolean[] value = new boolean[1];
            status = slave.readBoolean(vr, value);
            text = value[0] ? "1" : "0";
        } else {
            String[] value = new String[1];
            status = slave.readString(vr, value);
            text = csvField(value[0]);
        }
        if (status != FmiStatus.OK && status != FmiStatus.Warning) {
            throw new DriverException(fmuName + ": reading output " + v.getName() + " returned " + status);
        }
        return text;
    }

    private static Plan readPlan(Path planFile, ModelVariables variables) throws DriverException, IOException {
        Plan plan = new Plan();
        List<String> lines = Files.readAllLines(planFile, StandardCharsets.UTF_8);
        for (int i = 0; i < lines.size(); i++) {
            String line = lines.get(i).trim();
            String where = planFile + ":" + (i + 1);
            if (line.isEmpty() || line.startsWith("#")) {
                continue;
            }
            String[] f = fields(line);
            try {
                switch (f[0]) {
                    case "step_size":
                        expect(f, 2, where);
                        plan.stepSize = Double.parseDouble(f[1]);
                        if (!(plan.stepSize > 0.0)) {
                            throw new DriverException(where + ": step_size must be > 0, not " + f[1]);
                        }
                        break;
                    case "steps":
                        expect(f, 2, where);
                        plan.steps = Integer.parseInt(f[1]);
                        break;
                    case "start":
                        expect(f, 3, where);
                        plan.starts.add(new Assignment(variable(variables, f[1], where), f[2], where));
                        break;
                    case "input":
                        expect(f, 4, where);
                        plan.inputs.computeIfAbsent(Integer.parseInt(f[1]), k -> new ArrayList<>())
                                .add(new Assignment(variable(variables, f[2], where), f[3], where));
                        break;
                    default:
                        throw new DriverException(where + ": unknown directive '" + f[0]
                                + "' (step_size, steps, start, input)");
                }
            } catch (NumberFormatException e) {
                throw new DriverException(where + ": '" + line + "': " + e.getMessage());
            }
        }
        if (Double.isNaN(plan.stepSize) || plan.steps < 0) {
            throw new DriverException(planFile + ": needs a step_size line and a steps line");
        }
        return plan;
    }

    /**
     * The fields of a plan line. A variable name may hold commas (FMI 2 array elements "name[i,j]"): the
     * directive (and an input's step) come first, the value after the last comma, the name is what is between.
     */
    private static String[] fields(String line) {
        String[] head = line.split(",", 2);
        if (head.length == 1) {
            return head;
        }
        String rest = head[1];
        int last = rest.lastIndexOf(',');
        if (head[0].equals("start") && last >= 0) {
            return new String[] {head[0], rest.substring(0, last), rest.substring(last + 1)};
        }
        int first = rest.indexOf(',');
        if (head[0].equals("input") && first >= 0 && last > first) {
            return new String[] {head[0], rest.substring(0, first), rest.substring(first + 1, last),
                rest.substring(last + 1)};
        }
        return line.split(",", -1);
    }

    private static void expect(String[] fields, int count, String where) throws DriverException {
        if (fields.length != count) {
            throw new DriverException(where + ": '" + fields[0] + "' takes " + (count - 1) + " value(s), not "
                    + (fields.length - 1));
        }
    }

    private static TypedScalarVariable<?> variable(ModelVariables variables, String name, String where)
            throws DriverException {
        TypedScalarVariable<?> v = variables.getByNameOrNull(name);
        if (v == null) {
            throw new DriverException(where + ": the FMU has no variable '" + name + "'");
        }
        return v;
    }
}
