defmodule ThinkingCap.Config.HostileMapsTest do
  # ROS map files (YAML + PGM) from a hostile or careless hand: each is
  # loaded or refused with the file and a place, never raises, makes no
  # atom. Not async: the atom count it reads is the VM's.
  use ExUnit.Case, async: false

  alias ThinkingCap.Config.{Error, RosMap}

  @moduletag :tmp_dir
  @maps Path.expand("../../../../../priv/maps", __DIR__)
  # the real maps the fuzz test mutates (the small ones: a run stays short)
  @fuzzed ~w(testmap office turtlebot3_world)

  defp answered?(path) do
    case RosMap.load(path) do
      {:ok, %RosMap{}} ->
        true

      {:error, [_ | _] = errors} ->
        length(errors) <= 51 and
          Enum.all?(errors, fn %Error{} = e ->
            is_binary(e.file) and e.file != "" and is_binary(e.message) and
              (is_integer(e.offset) or (is_integer(e.line) and is_integer(e.column)))
          end)
    end
  end

  test "a YAML file of novel keys and values makes no atom", %{tmp_dir: dir} do
    prefix = "zq#{:erlang.unique_integer([:positive])}"

    text =
      Enum.map_join(1..2_000, "\n", &"#{prefix}k#{&1}: #{prefix}v#{&1}") <>
        "\nmode: #{prefix}mode\n"

    path = Path.join(dir, "atoms.yaml")
    File.write!(path, text)
    # the reader's code loaded first: loading a module makes atoms
    {:ok, _} = RosMap.load(Path.join(@maps, "testmap.yaml"))
    {:error, _} = RosMap.load(Path.join(@maps, "none.yaml"))
    before = :erlang.system_info(:atom_count)
    assert {:error, errors} = RosMap.load(path)
    # other processes of the VM may make a few atoms meanwhile; the file's
    # names (thousands) are not among them
    assert :erlang.system_info(:atom_count) - before < 200

    for name <- ["#{prefix}t1", "#{prefix}a1", "#{prefix}v1", "#{prefix}k1", "#{prefix}mode"],
        do: assert_raise(ArgumentError, fn -> String.to_existing_atom(name) end)

    assert length(errors) == 51
    assert List.last(errors).message =~ ~r/and \d+ more errors/
  end

  test "deep nesting in YAML is refused at its line, not handed to a parser", %{tmp_dir: dir} do
    path = Path.join(dir, "deep.yaml")
    File.write!(path, "image: x.pgm\norigin: " <> String.duplicate("[", 30_000) <> "\n")
    assert {:error, errors} = RosMap.load(path)
    assert Enum.any?(errors, &(&1.line == 2 and &1.message =~ "origin: [ here"))
  end

  test "a PGM whose header claims 10^9 cells is refused unread", %{tmp_dir: dir} do
    File.write!(Path.join(dir, "big.pgm"), "P5\n100000 10000\n255\n")
    path = Path.join(dir, "big.yaml")
    File.write!(path, "image: big.pgm\nresolution: 0.05\norigin: [0, 0]\n")
    assert {:error, [%Error{offset: 15, message: message}]} = RosMap.load(path)
    assert message =~ "1000000000 cells: a map is limited to 100000000 cells"
  end

  test "Config.check (mix tc.check) reads maps and takes readers of other kinds", %{
    tmp_dir: dir
  } do
    bad = Path.join(dir, "bad.yaml")
    File.write!(bad, "image: x.pgm\nresolution: 0\norigin: [0, 0]\n")
    good = Path.join(@maps, "testmap.yaml")

    assert [%Error{file: ^bad, line: 2, column: 13}] = ThinkingCap.Config.check([good, bad])

    other = fn path -> {:error, [Error.new(path, {3, 0}, "refused by its reader")]} end

    assert [%Error{file: "r.urdf", line: 3}] =
             ThinkingCap.Config.check(["r.urdf"], %{".urdf" => other})
  end

  test "fuzz: random and mutated YAML and PGM files are answered, never raise", %{
    tmp_dir: dir
  } do
    maps =
      for name <- @fuzzed do
        {File.read!(Path.join(@maps, name <> ".yaml")),
         File.read!(Path.join(@maps, name <> ".pgm"))}
      end

    edits =
      :proper_types.list(
        :proper_types.tuple([:proper_types.float(0.0, 1.0), :proper_types.byte()])
      )

    gen =
      :proper_types.oneof([
        # random bytes as the YAML, or as the image of a valid YAML
        :proper_types.tuple([:random_yaml, :proper_types.binary()]),
        :proper_types.tuple([:random_pgm, :proper_types.binary()]),
        # a real map with bytes of its YAML changed, or of its PGM's head,
        # and its PGM cut or lengthened
        :proper_types.tuple([
          :mutated,
          :proper_types.oneof(maps),
          edits,
          edits,
          :proper_types.oneof([:keep, :proper_types.float(0.0, 1.0), :proper_types.binary()])
        ])
      ])

    property =
      :proper.forall(gen, fn input ->
        {yaml, pgm} = files(input)
        File.write!(Path.join(dir, "f.pgm"), pgm)
        path = Path.join(dir, "f.yaml")
        File.write!(path, yaml)

        try do
          answered?(path)
        rescue
          # PropEr (as Debian ships it) cannot report an exception itself
          e ->
            flunk(
              "#{inspect({yaml, binary_part(pgm, 0, min(byte_size(pgm), 64))})} raised: " <>
                Exception.message(e)
            )
        end
      end)

    assert :proper.quickcheck(property, [
             {:numtests, 300},
             {:on_output, fn _format, _args -> :ok end},
             :long_result
           ]) == true
  end

  @good_yaml "image: f.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n"

  defp files({:random_yaml, bytes}), do: {bytes, "P5\n1 1\n255\n\0"}
  defp files({:random_pgm, bytes}), do: {@good_yaml, bytes}

  defp files({:mutated, {yaml, pgm}, yaml_edits, pgm_edits, tail}) do
    yaml = String.replace(yaml, ~r/^image:.*$/m, "image: f.pgm")
    head = min(byte_size(pgm), 96)
    <<pgm_head::binary-size(head), data::binary>> = pgm

    pgm =
      case tail do
        :keep -> mutate(pgm_head, pgm_edits) <> data
        cut when is_float(cut) -> binary_part(pgm, 0, trunc(cut * byte_size(pgm)))
        extra -> mutate(pgm_head, pgm_edits) <> data <> extra
      end

    {mutate(yaml, yaml_edits), pgm}
  end

  defp mutate("", _edits), do: ""

  defp mutate(source, edits) do
    Enum.reduce(edits, source, fn {at, byte}, s ->
      i = min(trunc(at * byte_size(s)), byte_size(s) - 1)
      <<head::binary-size(i), _, tail::binary>> = s
      <<head::binary, byte, tail::binary>>
    end)
  end
end
